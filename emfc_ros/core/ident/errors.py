"""
Errors and warnings of the identification core.

:class:`IdentificationError` subclasses :class:`~emfc_ros.core.errors.EmfcError` and
:class:`ValueError` so callers may catch either.
"""

from emfc_ros.core.errors import EmfcError


class IdentificationError(EmfcError, ValueError):
    """
    Identification cannot proceed with the given data or settings.

    The message names the offending argument and what is allowed.
    """


class IllConditionedFitWarning(UserWarning):
    """
    A least-squares design matrix is badly conditioned; parameters may be unreliable.

    Raised with :func:`warnings.warn`; the message gives the condition number and the limit.
    """
