"""
Error classes of bag writing, repair and reading back, one per concern.

Each subclasses :class:`~emfc_ros.core.errors.EmfcError` and the matching builtin so callers
may catch either.
"""

from emfc_ros.core.errors import EmfcError


class BagExistsError(EmfcError, FileExistsError):
    """The output folder exists and is not empty: a recording never overwrites a bag."""


class BagWriteError(EmfcError, OSError):
    """
    Writing the bag failed (disk full, file size limit, unwritable path).

    What was written before the failure stays on disk and can be repaired.
    """


class BagFormatError(EmfcError, OSError):
    """A bag folder or MCAP file is missing, damaged beyond repair or not a rosbag2 bag."""


class StreamGapError(EmfcError, ValueError):
    """A recorded block stream has missing samples (and gaps were asked to raise)."""
