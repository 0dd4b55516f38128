"""``python -m meshreg``: the command line, as the ``meshreg`` command (:func:`meshreg.cli.run`)."""

from .cli import run

if __name__ == "__main__":
    run()
