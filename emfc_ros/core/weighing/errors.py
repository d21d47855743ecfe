"""
The error class of the weighing core.

One class for every invalid weighing input or procedure; it subclasses ValueError.
"""


class WeighingError(ValueError):
    """
    A weighing input or procedure is invalid (the message names the argument and the rule).

    Subclasses :class:`ValueError`, so callers may catch either.
    """
