"""The two kinds of error meshreg reports to its user, each as one line that says what is wrong and what to do.

:class:`InputError`
    Bad input: a file, an array, a parameter, an output place. Raised before any long computation starts
    wherever that can be known; the command line prints it and exits with status 2.
:class:`RunError`
    A run that could not finish its work: pairs of a distance matrix without a value, outputs that could not
    be written. The command line prints it and exits with status 1; what was finished is kept (the message
    says where).
"""


class InputError(ValueError):
    """Bad input given by the user (file, array, parameter, output place): exit status 2."""


class RunError(RuntimeError):
    """A run that did not finish its work (pairs without a value, outputs not written): exit status 1."""
