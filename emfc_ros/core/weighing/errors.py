"""
The error class of the weighing core.

One class for every invalid weighing input or procedure; it subclasses EmfcError and
ValueError.
"""

from emfc_ros.core.errors import EmfcError


class WeighingError(EmfcError, ValueError):
    """
    A weighing input or procedure is invalid (the message names the argument and the rule).

    Subclasses :class:`~emfc_ros.core.errors.EmfcError` and :class:`ValueError`, so callers
    may catch either.
    """
