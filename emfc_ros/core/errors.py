"""
Error classes of the numerical core, one per concern.

Each subclasses the matching builtin so callers may catch either.
"""


class ConfigError(ValueError):
    """
    A configuration value is missing, of the wrong type or out of range.

    The message always names the offending key (dotted path) and what is allowed.
    """

    def __init__(self, key: str, problem: str) -> None:
        self.key = key
        self.problem = problem
        super().__init__(f'{key}: {problem}')


class SignalError(ValueError):
    """A signal cannot be generated as specified."""


class WaveformFileError(ValueError):
    """A waveform file (CSV or NPY) is unreadable or fails validation."""


class BlockError(ValueError):
    """A sample block does not follow the block convention."""
