"""Exit statuses and the one-line errors of the ``aeid-struct`` command."""

from __future__ import annotations

#: Exit status of a usage or input error (argparse's own convention).
EXIT_INPUT = 2
#: Exit status of ``identify`` when an estimate is flagged outside the training range.
EXIT_OUTSIDE = 3


class InputError(Exception):
    """A user's mistake (an argument, a file, a record).

    ``main`` prints it as one line and ends with ``EXIT_INPUT``; anything else that escapes a
    subcommand is a bug and keeps its traceback.
    """


class UsageExit(SystemExit):
    """How ``main`` ends on a usage or input error, after printing it as one line on stderr.

    A ``SystemExit`` with status ``EXIT_INPUT`` (what the interpreter exits with, printing
    nothing more) whose ``str()`` is the message, so that callers and tests can read it.

    Parameters
    ----------
    message : str
        The error, one line.
    """

    def __init__(self, message: str):
        super().__init__(EXIT_INPUT)
        self.message = message

    def __str__(self) -> str:
        return self.message


def one_line(err: object) -> str:
    """The text of ``err`` on one line (runs of whitespace, newlines included, as one space).

    Parameters
    ----------
    err : object
        An exception or any object with a ``str()``.

    Returns
    -------
    str
    """
    return " ".join(str(err).split())
