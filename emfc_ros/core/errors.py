"""
Error classes of the numerical core, one per concern, and the package's error root.

Every error class of emfc_ros subclasses :class:`EmfcError` and the matching builtin, so
callers may catch either. This module imports nothing from emfc_ros.
"""


class EmfcError(Exception):
    """
    The root of every error the package raises on purpose.

    Each concrete class also subclasses the matching builtin (:class:`ValueError`,
    :class:`OSError`, :class:`RuntimeError`...), so callers may catch either: a node catches
    ``EmfcError`` for everything emfc_ros refuses, old code keeps ``except ValueError``.
    Warnings (subclasses of :class:`Warning`) and interrupts (subclasses of
    :class:`KeyboardInterrupt`, which ``except Exception`` must not catch) do not subclass it.
    """


class ConfigError(EmfcError, ValueError):
    """
    A configuration value is missing, of the wrong type or out of range.

    The message always names the offending key (dotted path) and what is allowed.

    Parameters
    ----------
    key : str
        The offending key, a dotted path (``'plant.sample_rate_Hz'``).
    problem : str
        What is wrong and what is allowed; the message is ``'<key>: <problem>'``.
    """

    def __init__(self, key: str, problem: str) -> None:
        self.key = key
        self.problem = problem
        super().__init__(f'{key}: {problem}')


class SignalError(EmfcError, ValueError):
    """A signal cannot be generated as specified."""


class WaveformFileError(EmfcError, ValueError):
    """A waveform file (CSV or NPY) is unreadable or fails validation."""


class BlockError(EmfcError, ValueError):
    """A sample block does not follow the block convention."""
