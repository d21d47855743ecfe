"""
An MCAP file writer for many large messages: one copy of each message, one CRC pass.

It writes the same records, in the same order, as the ``mcap`` package's ``Writer`` with
``compression=NONE`` and ``enable_data_crcs=True`` (header; schema and channel records inside
the first chunk after them; uncompressed chunks with their CRC, each followed by its message
indexes; data end with the data section CRC; summary with schemas, channels, statistics,
chunk and metadata indexes, summary offsets; footer with the summary CRC). The rare records
are serialised by the ``mcap`` package's own record classes; only the two that carry the data,
message and chunk, are packed here, because the package's writer spends most of its time on
them (profiled in issue 14: a message is copied four times through ``BytesIO`` buffers and
every byte passes ``zlib.crc32`` twice, once for the chunk CRC and once for the data section
CRC).

Here a message is packed straight into a preallocated chunk buffer (one copy), the chunk's
CRC is computed once, and the data section CRC is extended over the chunk by combining the
two CRCs (:func:`crc32_combine`, zlib's algorithm) instead of a second pass over the data. The
chunk is handed to the file as a view of the buffer, without a further copy.
"""

from __future__ import annotations

import struct
from typing import BinaryIO, Dict, List, Tuple
import zlib

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (Channel, ChunkIndex, DataEnd, Footer, Header, Metadata,
                          MetadataIndex, Schema, Statistics, SummaryOffset)

MAGIC = b'\x89MCAP0\r\n'
# opcode, record length, channel id, sequence, log time, publish time
_MESSAGE = struct.Struct('<BQHIQQ')
# opcode, record length, start, end, uncompressed size, uncompressed CRC, compression
# string length (0: none), records length
_CHUNK = struct.Struct('<BQQQQIIQ')
_MESSAGE_INDEX_HEAD = struct.Struct('<BQHI')

# -- CRC-32 combination (zlib's crc32_combine, reflected polynomial 0xEDB88320) -------------

_POLY = 0xEDB88320


def _multmodp(a: int, b: int) -> int:
    """Product of two reflected polynomials modulo the CRC-32 polynomial."""
    m = 1 << 31
    p = 0
    while True:
        if a & m:
            p ^= b
            if not a & (m - 1):
                break
        m >>= 1
        b = (b >> 1) ^ _POLY if b & 1 else b >> 1
    return p


def _x2n_table() -> Tuple[int, ...]:
    """``x^(2^k)`` modulo the polynomial for k = 0..31."""
    p = 1 << 30          # x^1
    table = [p]
    for _ in range(31):
        p = _multmodp(p, p)
        table.append(p)
    return tuple(table)


_X2N = _x2n_table()


def crc32_combine(crc1: int, crc2: int, len2: int) -> int:
    """
    CRC-32 of ``A + B`` from ``crc32(A)``, ``crc32(B)`` and ``len(B)``.

    The algorithm of zlib's ``crc32_combine`` (multiplication by ``x^(8 len2)`` modulo the
    polynomial): about 0.1 ms for a megabyte chunk in Python, against about 0.4 ms for a
    second ``zlib.crc32`` pass over it.

    Parameters
    ----------
    crc1, crc2 : int
        CRC-32 of the first and of the second part.
    len2 : int
        Length of the second part [bytes].

    Returns
    -------
    int
        CRC-32 of the concatenation.
    """
    if len2 <= 0:
        return crc1
    p = 1 << 31          # x^0
    n, k = len2, 3       # x^(8 len2) = x^(len2 2^3)
    while n:
        if n & 1:
            p = _multmodp(_X2N[k & 31], p)
        n >>= 1
        k += 1
    return _multmodp(p, crc1) ^ crc2


def _record(write) -> bytes:
    """Serialise one record with the ``mcap`` package's record class."""
    builder = RecordBuilder()
    write(builder)
    return builder.end()


class McapFileWriter:
    """
    Write an uncompressed, chunked, indexed MCAP file with chunk and data section CRCs.

    The subset of ``mcap.writer.Writer``'s interface that :class:`~emfc_ros.core.bag.writer.
    BagWriter` uses, with the same output.

    Parameters
    ----------
    stream : binary file
        Opened for writing at its start; not closed here.
    chunk_size : int
        A chunk is closed once its records exceed this size [bytes].
    """

    def __init__(self, stream: BinaryIO, chunk_size: int = 1024 * 1024) -> None:
        self._stream = stream
        self._chunk_size = int(chunk_size)
        self._buf = bytearray(self._chunk_size + 65536)
        self._view = memoryview(self._buf)
        self._pos = 0                       # bytes of records in the chunk buffer
        self._n_chunk_messages = 0
        self._chunk_start_ns = 0
        self._chunk_end_ns = 0
        self._index: Dict[int, List[int]] = {}   # channel -> [time, offset, time, ...]
        self._offset = 0                    # bytes written to the file
        self._data_crc = 0
        self._schemas: Dict[int, Schema] = {}
        self._channels: Dict[int, Channel] = {}
        self._chunk_indexes: List[ChunkIndex] = []
        self._metadata_indexes: List[MetadataIndex] = []
        self._stats = Statistics(message_count=0, schema_count=0, channel_count=0,
                                 attachment_count=0, metadata_count=0, chunk_count=0,
                                 message_start_time=0, message_end_time=0,
                                 channel_message_counts={})

    # -- output ------------------------------------------------------------------------

    def _write(self, data) -> None:
        """Write bytes of the data section, extending its CRC."""
        self._data_crc = zlib.crc32(data, self._data_crc)
        self._stream.write(data)
        self._offset += len(data)

    def _append(self, data: bytes) -> None:
        """Append serialised records to the chunk buffer."""
        end = self._pos + len(data)
        if end > len(self._buf):
            self._grow(end)
        self._buf[self._pos:end] = data
        self._pos = end

    def _grow(self, size: int) -> None:
        self._view.release()
        self._buf.extend(bytes(size + self._chunk_size - len(self._buf)))
        self._view = memoryview(self._buf)

    # -- the mcap Writer interface -----------------------------------------------------

    def start(self, profile: str, library: str) -> None:
        """
        Write the magic and the header record.

        Parameters
        ----------
        profile, library : str
            Header fields.
        """
        self._write(MAGIC)
        self._write(_record(Header(profile, library).write))

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        """
        Add a schema record (into the chunk in progress).

        Parameters
        ----------
        name, encoding : str
            Schema name and encoding.
        data : bytes
            Schema text.

        Returns
        -------
        int
            The schema id (1, 2, ...).
        """
        sid = len(self._schemas) + 1
        schema = Schema(id=sid, data=data, encoding=encoding, name=name)
        self._schemas[sid] = schema
        self._stats.schema_count += 1
        self._append(_record(schema.write))
        return sid

    def register_channel(self, topic: str, message_encoding: str, schema_id: int,
                         metadata: Dict[str, str]) -> int:
        """
        Add a channel record (into the chunk in progress).

        Parameters
        ----------
        topic, message_encoding : str
            Channel fields.
        schema_id : int
            From :meth:`register_schema`.
        metadata : dict
            Channel metadata.

        Returns
        -------
        int
            The channel id (1, 2, ...).
        """
        cid = len(self._channels) + 1
        channel = Channel(id=cid, topic=topic, message_encoding=message_encoding,
                          schema_id=schema_id, metadata=metadata)
        self._channels[cid] = channel
        self._stats.channel_count += 1
        self._append(_record(channel.write))
        return cid

    def add_message(self, channel_id: int, log_time: int, data, publish_time: int,
                    sequence: int = 0) -> None:
        """
        Add one message to the chunk in progress; close the chunk when it is full.

        Parameters
        ----------
        channel_id : int
            From :meth:`register_channel`.
        log_time, publish_time : int
            Times [ns].
        data : bytes-like
            The serialised message.
        sequence : int
            Sequence number (32 bit).
        """
        size = len(data)
        pos = self._pos
        end = pos + _MESSAGE.size + size
        if end > len(self._buf):
            self._grow(end)
        _MESSAGE.pack_into(self._buf, pos, Opcode.MESSAGE, 22 + size, channel_id, sequence,
                           log_time, publish_time)
        self._view[pos + _MESSAGE.size:end] = data
        self._pos = end
        entries = self._index.get(channel_id)
        if entries is None:
            entries = self._index[channel_id] = []
        entries.append(log_time)
        entries.append(pos)
        if self._n_chunk_messages:
            if log_time < self._chunk_start_ns:
                self._chunk_start_ns = log_time
            if log_time > self._chunk_end_ns:
                self._chunk_end_ns = log_time
        else:
            self._chunk_start_ns = self._chunk_end_ns = log_time
        self._n_chunk_messages += 1
        stats = self._stats
        if stats.message_count:
            if log_time < stats.message_start_time:
                stats.message_start_time = log_time
            if log_time > stats.message_end_time:
                stats.message_end_time = log_time
        else:
            stats.message_start_time = stats.message_end_time = log_time
        stats.message_count += 1
        counts = stats.channel_message_counts
        counts[channel_id] = counts.get(channel_id, 0) + 1
        if end > self._chunk_size:
            self._finish_chunk()

    def _finish_chunk(self) -> None:
        if not self._n_chunk_messages:
            return
        self._stats.chunk_count += 1
        size = self._pos
        records = self._view[:size]
        crc = zlib.crc32(records)
        start = self._offset
        head = _CHUNK.pack(Opcode.CHUNK, 8 + 8 + 8 + 4 + 4 + 8 + size, self._chunk_start_ns,
                           self._chunk_end_ns, size, crc, 0, size)
        self._data_crc = zlib.crc32(head, self._data_crc)
        self._data_crc = crc32_combine(self._data_crc, crc, size)
        self._stream.write(head)
        self._stream.write(records)
        records.release()
        self._offset += len(head) + size
        chunk_length = self._offset - start
        index_start = self._offset
        offsets = {}
        for cid, entries in self._index.items():
            offsets[cid] = self._offset
            n = len(entries)
            self._write(_MESSAGE_INDEX_HEAD.pack(Opcode.MESSAGE_INDEX, 6 + 8 * n, cid, 8 * n)
                        + struct.pack(f'<{n}Q', *entries))
        self._chunk_indexes.append(ChunkIndex(
            message_start_time=self._chunk_start_ns, message_end_time=self._chunk_end_ns,
            chunk_start_offset=start, chunk_length=chunk_length,
            message_index_offsets=offsets, message_index_length=self._offset - index_start,
            compression='', compressed_size=size, uncompressed_size=size))
        self._pos = 0
        self._n_chunk_messages = 0
        self._index = {}

    def flush(self) -> None:
        """Close the chunk in progress (if it holds a message) and flush the stream."""
        self._finish_chunk()
        self._stream.flush()

    def add_metadata(self, name: str, data: Dict[str, str]) -> None:
        """
        Write a metadata record (the chunk in progress goes on, as in the ``mcap`` writer).

        Parameters
        ----------
        name : str
            Record name.
        data : dict
            Key-value pairs.
        """
        offset = self._offset
        self._stats.metadata_count += 1
        raw = _record(Metadata(name=name, metadata=data).write)
        self._write(raw)
        self._metadata_indexes.append(MetadataIndex(offset=offset, length=len(raw), name=name))

    def finish(self) -> None:
        """Close the chunk in progress and write data end, summary, footer and magic."""
        self._finish_chunk()
        self._write(_record(DataEnd(self._data_crc).write))
        summary_start = self._offset
        builder = RecordBuilder()
        offsets = []

        def group(opcode: int, records) -> None:
            first = builder.count
            for record in records:
                record.write(builder)
            offsets.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + first,
                                         group_length=builder.count - first))

        group(Opcode.SCHEMA, self._schemas.values())
        group(Opcode.CHANNEL, self._channels.values())
        group(Opcode.STATISTICS, [self._stats])
        group(Opcode.CHUNK_INDEX, self._chunk_indexes)
        group(Opcode.ATTACHMENT_INDEX, [])
        group(Opcode.METADATA_INDEX, self._metadata_indexes)
        summary_offset_start = summary_start + builder.count
        for offset in offsets:
            offset.write(builder)
        summary = builder.end()
        summary_crc = zlib.crc32(summary)
        summary_crc = zlib.crc32(struct.pack('<BQQQ', Opcode.FOOTER, 8 + 8 + 4, summary_start,
                                             summary_offset_start), summary_crc)
        self._stream.write(summary)
        self._stream.write(_record(Footer(summary_start=summary_start,
                                          summary_offset_start=summary_offset_start,
                                          summary_crc=summary_crc).write))
        self._stream.write(MAGIC)
        self._offset += len(summary)
