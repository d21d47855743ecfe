"""
A rosbag2 bag writer with MCAP storage that splits files and flushes on demand.

Layout as ``ros2 bag record -s mcap``: a folder ``<name>/`` holding ``metadata.yaml``
(version 9) and ``<name>_0.mcap``, ``<name>_1.mcap``, ... Each MCAP file has the ``ros2``
profile, ``ros2msg`` schemas (so independent readers decode it), ``cdr`` channels whose
metadata carries ``offered_qos_profiles`` and ``topic_type_hash`` as rosbag2 writes them,
uncompressed chunks with message indexes, and a summary; chunk, data section and summary
CRCs (the data section CRC lets repair check a whole file in one pass).

Crash safety: :meth:`BagWriter.flush` closes the chunk in progress, writes it to the file and
fsyncs, and rewrites a provisional ``metadata.yaml``; everything written before the last flush
survives a killed process and is recovered by :func:`emfc_ros.core.bag.repair.repair_bag`.

The MCAP files are written by :class:`~emfc_ros.core.bag.mcap_file.McapFileWriter`, which
writes byte for byte what the ``mcap`` package's writer writes (its records, its ``flush``
closing a chunk on demand, which rosbags' writer does not offer) with one copy and one CRC
pass per message instead of four copies and two passes; message definitions, hashes and QoS
text come from the pinned rosbags typestore, so readers see the same schemas as rosbags
writes.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any, BinaryIO, Dict, List, Optional, Sequence

from emfc_ros import __version__ as _package_version
from emfc_ros.core.bag.errors import BagExistsError, BagWriteError
from emfc_ros.core.bag.mcap_file import McapFileWriter
from emfc_ros.core.bag.metadata import (
    build_metadata, dump_metadata, FileStats, TopicStats, write_metadata)
from emfc_ros.core.bag.msgdefs import MessageTypes
from emfc_ros.core.bag.qos import OfferedQos, qos_list, qos_yaml

PROFILE = 'ros2'
LIBRARY = f'emfc_ros-{_package_version}'
DEFAULT_CHUNK_SIZE_B = 1024 * 1024
# Record overhead of an MCAP message (opcode, length, channel, sequence, two times).
_MESSAGE_OVERHEAD_B = 31


@dataclasses.dataclass
class _Connection:
    id: int
    topic: str
    msgtype: str
    msgdef: str
    rihs01: str
    qos: List[OfferedQos]
    stats: TopicStats
    bytes: int = 0


class BagWriter:
    """
    Write a rosbag2 bag (metadata version 9, MCAP storage), splitting files like rosbag2.

    Not thread-safe: one thread owns it (see :class:`emfc_ros.core.bag.recording.
    QueuedBagWriter` for the recorder's writer thread).

    Parameters
    ----------
    path : str or pathlib.Path
        Bag folder to create; an existing empty folder is accepted, a non-empty one refused.
    max_bag_size_B : int
        Split when the current file reaches this size [bytes]; 0: no size split.
    max_bag_duration_ns : int
        Split when a message is this much later than the current file's first one [ns];
        0: no duration split.
    chunk_size_B : int
        MCAP chunk size [bytes]; a flush also closes the chunk in progress.
    types : MessageTypes, optional
        Message definitions; the Jazzy typestore when absent.
    fsync : bool
        Whether :meth:`flush` also fsyncs the file (survives power loss, not only a crash).
    ros_distro : str
        Stored in the metadata.
    """

    def __init__(self, path, *, max_bag_size_B: int = 0, max_bag_duration_ns: int = 0,
                 chunk_size_B: int = DEFAULT_CHUNK_SIZE_B, types: Optional[MessageTypes] = None,
                 fsync: bool = True, ros_distro: str = 'jazzy') -> None:
        if max_bag_size_B < 0 or max_bag_duration_ns < 0 or chunk_size_B <= 0:
            raise ValueError('max_bag_size_B and max_bag_duration_ns must be >= 0 and '
                             'chunk_size_B > 0')
        self.path = Path(path)
        self.max_bag_size_B = int(max_bag_size_B)
        self.max_bag_duration_ns = int(max_bag_duration_ns)
        self.chunk_size_B = int(chunk_size_B)
        if self.max_bag_size_B:
            # Split close to the requested size: chunks no larger than a quarter of it.
            self.chunk_size_B = max(4096, min(self.chunk_size_B, self.max_bag_size_B // 4))
        self.types = types or MessageTypes()
        self.fsync = fsync
        self.ros_distro = ros_distro
        self.custom_data: Dict[str, str] = {}
        self.files: List[FileStats] = []
        self._connections: List[_Connection] = []
        self._stream: Optional[BinaryIO] = None
        self._mcap: Optional[McapFileWriter] = None
        self._channel_ids: Dict[int, int] = {}
        self._sequence: Dict[int, int] = {}
        self._file_bytes = 0
        self.bytes_written = 0
        self.is_open = False

    # -- public API ------------------------------------------------------------------------

    @property
    def name(self) -> str:
        """
        The bag's name: the folder name, stem of every storage file.

        Returns
        -------
        str
            The name.
        """
        return self.path.name

    @property
    def message_count(self) -> int:
        """
        Messages written so far.

        Returns
        -------
        int
            Sum over files.
        """
        return sum(f.message_count for f in self.files)

    @property
    def topics(self) -> List[TopicStats]:
        """
        Per-topic statistics.

        Returns
        -------
        list of TopicStats
            One per connection.
        """
        return [c.stats for c in self._connections]

    def topic_bytes(self) -> Dict[str, int]:
        """
        Serialized bytes written per topic.

        Returns
        -------
        dict
            Topic name to bytes [B].
        """
        return {c.topic: c.bytes for c in self._connections}

    def open(self) -> None:
        """
        Create the bag folder, the first storage file and a provisional metadata.yaml.

        Raises
        ------
        BagExistsError
            If the folder exists and is not empty.
        BagWriteError
            If the folder or file cannot be created.
        """
        if self.path.exists() and not self.path.is_dir():
            raise BagWriteError(f'cannot create bag folder {self.path}: a file of that name '
                                'exists')
        if self.path.is_dir() and any(self.path.iterdir()):
            raise BagExistsError(f'bag folder {self.path} exists and is not empty; choose '
                                 'another output or remove it')
        try:
            self.path.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise BagWriteError(f'cannot create bag folder {self.path}: {exc}') from exc
        self.is_open = True
        self._open_file()
        self.write_metadata()

    def set_custom_data(self, key: str, value: str) -> None:
        """
        Set one entry of the metadata's ``custom_data`` (written at the next flush).

        Parameters
        ----------
        key : str
            The key, conventionally ``'<package>.<name>'``.
        value : str
            The value.

        Raises
        ------
        TypeError
            If the value is not a string.
        """
        if not isinstance(value, str):
            raise TypeError(f'custom_data value of {key!r} must be a string')
        self.custom_data[str(key)] = value

    def add_connection(self, topic: str, msgtype: str,
                       offered_qos: Sequence[OfferedQos] = (),
                       msgdef: Optional[str] = None, rihs01: Optional[str] = None) -> int:
        """
        Register a topic; returns the connection id to pass to :meth:`write`.

        Parameters
        ----------
        topic : str
            Topic name.
        msgtype : str
            Message type, for example ``'std_msgs/msg/Float64MultiArray'``.
        offered_qos : sequence of OfferedQos
            The publishers' offered QoS.
        msgdef, rihs01 : str, optional
            Definition and hash; from the typestore when absent.

        Returns
        -------
        int
            The connection id (1, 2, ...).

        Raises
        ------
        emfc_ros.core.bag.msgdefs.MessageTypeError
            If the type has no known definition.
        BagWriteError
            If writing the channel fails.
        """
        if msgdef is None or rihs01 is None:
            msgdef, rihs01 = self.types.definition(msgtype)
        cid = len(self._connections) + 1
        stats = TopicStats(name=topic, msgtype=msgtype,
                           offered_qos_profiles=qos_list(offered_qos),
                           type_description_hash=rihs01)
        conn = _Connection(cid, topic, msgtype, msgdef, rihs01, list(offered_qos), stats)
        self._connections.append(conn)
        self._sequence[cid] = 0
        if self._mcap is not None:
            self._guard(self._register, conn)
        return cid

    def write(self, connection_id: int, timestamp_ns: int, data: bytes) -> None:
        """
        Write one serialized (CDR) message.

        Parameters
        ----------
        connection_id : int
            From :meth:`add_connection`.
        timestamp_ns : int
            Receive time [ns].
        data : bytes
            The serialized message.

        Raises
        ------
        BagWriteError
            If the write fails (disk full, file size limit...).
        """
        if self._mcap is None:
            raise BagWriteError(f'bag {self.path} is not open')
        conn = self._connections[connection_id - 1]
        current = self.files[-1]
        if current.message_count and (
                (self.max_bag_size_B and self._file_bytes >= self.max_bag_size_B)
                or (self.max_bag_duration_ns
                    and timestamp_ns - current.start_ns >= self.max_bag_duration_ns)):
            self.split()
            current = self.files[-1]
        seq = self._sequence[connection_id] = self._sequence[connection_id] + 1
        self._guard(self._mcap.add_message, self._channel_ids[connection_id], timestamp_ns,
                    data, timestamp_ns, seq & 0xFFFFFFFF)
        size = len(data)
        self._file_bytes += size + _MESSAGE_OVERHEAD_B
        self.bytes_written += size
        conn.bytes += size
        conn.stats.message_count += 1
        current.add(timestamp_ns)

    def flush(self) -> None:
        """
        Put everything written so far on disk and rewrite the provisional metadata.yaml.

        Raises
        ------
        BagWriteError
            If writing fails.
        """
        if self._mcap is None:
            return
        self._guard(self._flush_file)
        self._guard(self.write_metadata)

    def split(self) -> None:
        """
        Finish the current storage file and continue in the next one.

        Raises
        ------
        BagWriteError
            If writing fails.
        """
        self._finish_file()
        self._open_file()
        self.write_metadata()

    def close(self) -> None:
        """
        Finish the current storage file (summary, footer) and write the final metadata.yaml.

        Raises
        ------
        BagWriteError
            If writing fails; what was flushed before stays repairable.
        """
        if not self.is_open:
            return
        try:
            if self._mcap is not None:
                self._finish_file()
            self._guard(self.write_metadata)
        finally:
            self.is_open = False

    def abort(self) -> None:
        """Close the file handle without summary after an error (the bag stays repairable)."""
        stream, self._stream, self._mcap = self._stream, None, None
        self.is_open = False
        if stream is not None:
            try:
                stream.close()
            except OSError:
                pass

    def metadata(self) -> Dict[str, Any]:
        """
        The current ``metadata.yaml`` content.

        Returns
        -------
        dict
            As :func:`emfc_ros.core.bag.metadata.build_metadata` returns.
        """
        return build_metadata(self.files, self.topics, self.custom_data, self.ros_distro)

    def write_metadata(self) -> None:
        """
        Write ``metadata.yaml`` now.

        Raises
        ------
        BagWriteError
            If writing fails.
        """
        self._guard(write_metadata, self.path, self.metadata())

    # -- internals -------------------------------------------------------------------------

    def _guard(self, func, *args):
        try:
            return func(*args)
        except BagWriteError:
            raise
        except OSError as exc:
            raise BagWriteError(f'writing bag {self.path} failed: {exc}') from exc

    def _open_file(self) -> None:
        name = f'{self.name}_{len(self.files)}.mcap'
        try:
            self._stream = open(self.path / name, 'xb')
        except OSError as exc:
            raise BagWriteError(f'cannot create {self.path / name}: {exc}') from exc
        self._mcap = McapFileWriter(self._stream, chunk_size=self.chunk_size_B)
        self.files.append(FileStats(name))
        self._channel_ids = {}
        self._schema_ids: Dict[str, int] = {}
        self._file_bytes = 0
        self._guard(self._mcap.start, PROFILE, LIBRARY)
        for conn in self._connections:
            self._guard(self._register, conn)

    def _register(self, conn: _Connection) -> None:
        assert self._mcap is not None
        if conn.msgtype not in self._schema_ids:
            self._schema_ids[conn.msgtype] = self._mcap.register_schema(
                conn.msgtype, 'ros2msg', conn.msgdef.encode())
        self._channel_ids[conn.id] = self._mcap.register_channel(
            conn.topic, 'cdr', self._schema_ids[conn.msgtype],
            {'offered_qos_profiles': qos_yaml(conn.qos), 'topic_type_hash': conn.rihs01})
        self._file_bytes += len(conn.msgdef) + 256

    def _flush_file(self) -> None:
        assert self._mcap is not None and self._stream is not None
        self._mcap.flush()
        if self.fsync:
            os.fsync(self._stream.fileno())

    def _finish_file(self) -> None:
        mcap, stream = self._mcap, self._stream
        assert mcap is not None and stream is not None
        try:
            mcap.add_metadata('rosbag2', {'serialized_metadata': dump_metadata(
                self.metadata()['rosbag2_bagfile_information'])})
            mcap.finish()
            stream.flush()
            if self.fsync:
                os.fsync(stream.fileno())
            stream.close()
        except OSError as exc:
            self.abort()
            raise BagWriteError(f'writing bag {self.path} failed: {exc}') from exc
        self._mcap = self._stream = None
