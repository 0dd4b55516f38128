"""Errors raised on bad input.

Every check in meshreg raises :class:`InputError` with a one-line message that says what is wrong
and what to do; the command line prints that line and exits non-zero.
"""


class InputError(ValueError):
    """Bad input given by the user (file, array, parameter)."""
