"""The one error base of `calib`: every mistake in a model, table, chain, cell, plan or fit it is given is a
CalibError, and calib raises nothing else for its input (Python's own errors met inside a parser are caught there
and re-raised as one).

The command line catches this base (one line, exit 2); each module refines it with what went wrong, and a caller
that handles one mistake catches that subclass. Not a ValueError: a ValueError from inside calib is a bug.
"""


class CalibError(Exception):
    """Input that the mathematics cannot use; the message names the file, row or key where it can."""
