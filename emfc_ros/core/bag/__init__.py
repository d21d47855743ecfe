"""
rosbag2 bags (metadata version 9, MCAP storage): writing, repair and reading back.

No ROS import here: bags are written with the ``mcap`` package and rosbags' pinned Jazzy
typestore, read with rosbags. See ``docs/recording.md``.
"""

from emfc_ros.core.bag.errors import (
    BagExistsError, BagFormatError, BagWriteError, StreamGapError)
from emfc_ros.core.bag.metadata import custom_data, read_metadata
from emfc_ros.core.bag.msgdefs import MessageTypeError, MessageTypes
from emfc_ros.core.bag.qos import OfferedQos
from emfc_ros.core.bag.reader import BagDamageWarning, read_messages, read_streams, Stream
from emfc_ros.core.bag.recording import QueuedBagWriter, RecorderStats
from emfc_ros.core.bag.repair import repair_bag, RepairReport
from emfc_ros.core.bag.scan import ChunkDamage
from emfc_ros.core.bag.writer import BagWriter

__all__ = ['BagDamageWarning', 'BagExistsError', 'BagFormatError', 'BagWriteError', 'BagWriter',
           'ChunkDamage', 'custom_data', 'MessageTypeError', 'MessageTypes', 'OfferedQos',
           'QueuedBagWriter', 'read_messages', 'read_metadata', 'read_streams',
           'RecorderStats', 'repair_bag', 'RepairReport', 'Stream', 'StreamGapError']
