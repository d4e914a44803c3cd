"""The one error base of `calib`: every mistake in a model, table, chain or cell it is given is a CalibError.

The command line catches this base (one line, exit 2); each module refines it with what went wrong.
"""


class CalibError(ValueError):
    """Input that the mathematics cannot use; the message names the file, row or key where it can."""
