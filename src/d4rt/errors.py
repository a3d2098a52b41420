"""Errors that carry a one-line message meant for the user (bad input, not a bug)."""


class UserError(ValueError):
    """Bad input from the user: the message names the problem in one line.

    The CLI prints it without a traceback and exits with status 2.
    """


class DegenerateFit(UserError):
    """The points given leave a fit undetermined (too few valid points, collinear ones, every point behind the
    camera). From a model's answers it is a property of the weights, not of the call: validation during
    training records it for that clip and goes on."""
