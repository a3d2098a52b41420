"""Errors that carry a one-line message meant for the user (bad input, not a bug)."""


class UserError(ValueError):
    """Bad input from the user: the message names the problem in one line.

    The CLI prints it without a traceback and exits with status 2.
    """
