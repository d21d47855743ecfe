"""
Error classes of bag writing, repair and reading back, one per concern.

Each subclasses the matching builtin so callers may catch either.
"""


class BagExistsError(FileExistsError):
    """The output folder exists and is not empty: a recording never overwrites a bag."""


class BagWriteError(OSError):
    """
    Writing the bag failed (disk full, file size limit, unwritable path).

    What was written before the failure stays on disk and can be repaired.
    """


class BagFormatError(OSError):
    """A bag folder or MCAP file is missing, damaged beyond repair or not a rosbag2 bag."""


class StreamGapError(ValueError):
    """A recorded block stream has missing samples (and gaps were asked to raise)."""
