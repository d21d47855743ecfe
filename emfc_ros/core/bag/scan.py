"""
Read an MCAP storage file record by record, checking every chunk CRC and skipping bad chunks.

The reader (:func:`emfc_ros.core.bag.reader.read_streams`) falls back to this when rosbags
stops at a damaged chunk, and repair (:func:`emfc_ros.core.bag.repair.repair_bag`) uses it to
rebuild a file from its intact records. Two ways through a file:

* indexed: the file has its summary (footer, chunk indexes), so every chunk is found at the
  offset its index gives, and a chunk whose CRC (or record) is bad is skipped; what was lost
  (messages, topics, time range) comes from the chunk index and its message indexes, which
  lie outside the chunk;
* sequential: without a usable summary (a killed recorder), records are read from the start;
  a chunk whose CRC is bad is skipped when its record framing is intact, and the message
  indexes that follow it say what was lost; reading stops at the first record that cannot be
  framed (truncation).

A :class:`ChunkDamage` describes each skipped chunk: file, byte offset, time range, messages.
"""

from __future__ import annotations

import dataclasses
from io import BytesIO
import os
from pathlib import Path
import struct
from typing import BinaryIO, Dict, Iterator, List, Optional, Tuple
import zlib

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import (Channel, Chunk, ChunkIndex, DataEnd, Footer, Header, McapRecord,
                          Message, MessageIndex, Metadata, Schema)
from mcap.stream_reader import breakup_chunk, get_chunk_data_stream

MAGIC = b'\x89MCAP0\r\n'
_PREFIX_B = 9  # opcode (1 B) and record length (8 B)
_FOOTER_B = _PREFIX_B + 8 + 8 + 4  # summary start, summary offset start, summary CRC
_DATA_END_B = _PREFIX_B + 4        # data section CRC
_PARSERS = {Opcode.CHANNEL: Channel.read, Opcode.CHUNK: Chunk.read,
            Opcode.CHUNK_INDEX: ChunkIndex.read, Opcode.DATA_END: DataEnd.read,
            Opcode.FOOTER: Footer.read, Opcode.HEADER: Header.read,
            Opcode.MESSAGE_INDEX: MessageIndex.read, Opcode.METADATA: Metadata.read,
            Opcode.SCHEMA: Schema.read}


@dataclasses.dataclass
class ChunkDamage:
    """
    One chunk of an MCAP file that could not be read (CRC mismatch or a damaged record).

    Attributes
    ----------
    file : str
        The storage file (as given to the scan).
    offset_B : int
        Byte offset of the chunk record in the file [B].
    length_B : int
        Length of the chunk record, prefix included [B]; 0 if unknown.
    start_ns : int or None
        Log time of the chunk's first message [ns], if known.
    end_ns : int or None
        Log time of its last message [ns], if known.
    message_count : int or None
        Messages lost with it, if known (from its message indexes).
    topics : tuple of str
        Topics that had messages in it, if known.
    error : str
        What was wrong.
    """

    file: str
    offset_B: int
    length_B: int
    start_ns: Optional[int]
    end_ns: Optional[int]
    message_count: Optional[int]
    topics: Tuple[str, ...]
    error: str

    @property
    def duration_s(self) -> float:
        """
        Time span of the lost messages [s] (0 if unknown).

        Returns
        -------
        float
            ``(end_ns - start_ns) / 1e9``.
        """
        if self.start_ns is None or self.end_ns is None or self.end_ns < self.start_ns:
            return 0.0
        return (self.end_ns - self.start_ns) / 1e9

    def describe(self) -> str:
        """
        One line for people.

        Returns
        -------
        str
            File, offset, what was lost and why.
        """
        count = '?' if self.message_count is None else str(self.message_count)
        span = (f', log time {self.start_ns / 1e9:.9f} s to {self.end_ns / 1e9:.9f} s'
                if self.start_ns is not None and self.end_ns is not None else '')
        topics = f' of {", ".join(self.topics)}' if self.topics else ''
        return (f'{self.file}: corrupt chunk at byte {self.offset_B} ({self.error}): '
                f'{count} messages{topics} lost{span}')


class McapScan:
    """
    The readable records of one MCAP file, in file order, with the damage found.

    Iterate :meth:`records` once; afterwards :attr:`damage` lists the skipped chunks,
    :attr:`complete` says whether the file was read to its end of data, :attr:`end_B` is
    the offset after the last record read, :attr:`error` why reading stopped early,
    :attr:`chunks` how many chunks were met, :attr:`summary_damaged` whether the file was
    finished (data end record) but its summary, footer or trailing magic is missing, fails
    its CRC or cannot be read (so it was read sequentially), and :attr:`magic_damaged`
    whether the leading magic bytes were wrong.

    Parameters
    ----------
    path : str or pathlib.Path
        The MCAP file.
    name : str, optional
        Name for the damage reports (the path when absent).
    expand : bool
        Yield the records inside chunks; False only checks the chunks (CRC included) and
        yields the records outside them.
    """

    def __init__(self, path, name: Optional[str] = None, expand: bool = True) -> None:
        self.path = Path(path)
        self.name = name or str(path)
        self.expand = expand
        self.damage: List[ChunkDamage] = []
        self.complete = False
        self.end_B = 0
        self.error = ''
        self.chunks = 0
        self.summary_damaged = False
        self.magic_damaged = False

    def records(self) -> Iterator[McapRecord]:
        """
        Yield the Schema, Channel, Message and Metadata records that can be read.

        Chunks are expanded into their records; a chunk that fails its CRC or cannot be
        parsed is skipped and added to :attr:`damage`.

        Yields
        ------
        mcap.records.McapRecord
            Records in file order.
        """
        with open(self.path, 'rb') as handle:
            summary = read_summary(handle)
            if summary is not None:
                yield from self._indexed(handle, summary)
            else:
                handle.seek(0)
                yield from self._sequential(handle)
                # Finished (DataEnd or footer found) but no usable summary: damaged at the end.
                self.summary_damaged = self.complete

    # -- indexed: the summary is there ---------------------------------------------------

    def _indexed(self, handle: BinaryIO, summary) -> Iterator[McapRecord]:
        topics = {cid: c.topic for cid, c in summary.channels.items()}
        yield from summary.schemas.values()
        yield from summary.channels.values()
        for index in sorted(summary.metadata_indexes, key=lambda i: i.offset):
            try:
                record = _read_at(handle, index.offset, index.length)
            except Exception:  # noqa: S112 - a damaged metadata record is only metadata
                continue
            if isinstance(record, Metadata):
                yield record
        for index in sorted(summary.chunk_indexes, key=lambda i: i.chunk_start_offset):
            self.chunks += 1
            try:
                chunk = _read_at(handle, index.chunk_start_offset, index.chunk_length)
                if not isinstance(chunk, Chunk):
                    raise ValueError('no chunk record at the indexed offset')
                records = self._open_chunk(chunk)
            except Exception as exc:  # CRC, framing, decompression: the chunk is lost
                self.damage.append(self._damage_from_index(handle, index, topics, exc))
                continue
            for record in records:
                if isinstance(record, Message):
                    yield record
        self.complete = True
        self.end_B = handle.seek(0, os.SEEK_END)

    def _damage_from_index(self, handle: BinaryIO, index: ChunkIndex,
                           topics: Dict[int, str], exc: Exception) -> ChunkDamage:
        count: Optional[int] = None
        total = 0
        for offset in index.message_index_offsets.values():
            try:
                record = _read_at(handle, offset, 0)
                total += len(record.records) if isinstance(record, MessageIndex) else 0
            except Exception:  # an unreadable message index: the count is unknown
                break
        else:
            count = total
        return ChunkDamage(
            self.name, index.chunk_start_offset, index.chunk_length, index.message_start_time,
            index.message_end_time, count,
            tuple(sorted({topics.get(cid, f'channel {cid}')
                          for cid in index.message_index_offsets})), _describe(exc))

    def _open_chunk(self, chunk: Chunk) -> List[McapRecord]:
        if self.expand:
            return breakup_chunk(chunk, validate_crc=True)
        get_chunk_data_stream(chunk, validate_crc=True)
        return []

    # -- sequential: no summary ----------------------------------------------------------

    def _sequential(self, handle: BinaryIO) -> Iterator[McapRecord]:
        size = handle.seek(0, os.SEEK_END)
        handle.seek(0)
        magic = handle.read(len(MAGIC))
        if magic != MAGIC and (len(magic) < len(MAGIC) or handle.read(1) != bytes(
                [Opcode.HEADER])):
            self.error = 'no MCAP magic at the start'
            return
        self.magic_damaged = magic != MAGIC      # a damaged magic, a header after it: go on
        handle.seek(len(MAGIC))
        self.end_B = pos = len(MAGIC)
        topics: Dict[int, str] = {}
        lost: Optional[ChunkDamage] = None
        while True:
            prefix = handle.read(_PREFIX_B)
            if len(prefix) < _PREFIX_B:
                self.error = 'truncated' if prefix or pos < size else 'no footer'
                return
            opcode, length = struct.unpack('<BQ', prefix)
            if length > size - pos - _PREFIX_B:
                self.error = f'truncated record (opcode {opcode:#04x}, {length} B)'
                return
            body = handle.read(length)
            if opcode == Opcode.MESSAGE_INDEX and lost is not None:
                try:
                    index = MessageIndex.read(ReadDataStream(BytesIO(body)))
                    lost.message_count = (lost.message_count or 0) + len(index.records)
                    lost.topics = tuple(sorted(set(lost.topics) | {
                        topics.get(index.channel_id, f'channel {index.channel_id}')}))
                except Exception:  # noqa: S110 - the count stays unknown
                    pass
            elif opcode != Opcode.MESSAGE_INDEX:
                lost = None
            if opcode == Opcode.CHUNK:
                self.chunks += 1
                try:
                    chunk = Chunk.read(ReadDataStream(BytesIO(body)))
                    records = self._open_chunk(chunk)
                except Exception as exc:  # CRC or a damaged chunk: skip it, go on
                    start, end = _chunk_times(body)
                    lost = ChunkDamage(self.name, pos, _PREFIX_B + length, start, end, None,
                                       (), _describe(exc))
                    self.damage.append(lost)
                    records = []
                for record in records:
                    if isinstance(record, Channel):
                        topics[record.id] = record.topic
                    yield record
            elif opcode in _PARSERS:
                try:
                    record = _PARSERS[opcode](ReadDataStream(BytesIO(body)))
                except Exception as exc:  # a damaged record outside chunks: stop here
                    self.error = f'damaged record at byte {pos}: {_describe(exc)}'
                    return
                if isinstance(record, (DataEnd, Footer)):
                    # The summary after DataEnd repeats what the data section said.
                    self.complete = True
                    self.end_B = handle.seek(0, os.SEEK_END)
                    return
                if isinstance(record, Channel):
                    topics[record.id] = record.topic
                if isinstance(record, (Schema, Channel, Metadata)):
                    yield record
            elif opcode == Opcode.MESSAGE:
                yield Message.read(ReadDataStream(BytesIO(body)), length)
            pos += _PREFIX_B + length
            self.end_B = pos


def read_summary(handle: BinaryIO):
    """
    The summary of an MCAP file that has a footer and chunk indexes for its messages.

    Parameters
    ----------
    handle : file
        The file, opened for binary reading.

    Returns
    -------
    mcap.summary.Summary or None
        None when the file has no summary, one that fails the footer's CRC or cannot be
        read, or messages outside chunks.
    """
    try:
        size = handle.seek(0, os.SEEK_END)
        if size < 2 * len(MAGIC):
            return None
        handle.seek(size - len(MAGIC))
        if handle.read(len(MAGIC)) != MAGIC:
            return None
        if not _summary_crc_ok(handle, size):
            return None
        handle.seek(0)
        summary = make_reader(handle).get_summary()
    except Exception:  # a damaged summary: read the file sequentially
        return None
    if summary is None or summary.statistics is None:
        return None
    if summary.statistics.message_count and not summary.chunk_indexes:
        return None  # messages outside chunks: only the sequential pass sees them
    return summary


def _summary_crc_ok(handle: BinaryIO, size: int) -> bool:
    """Whether the summary section matches the footer's CRC (True when there is none)."""
    footer_at = size - len(MAGIC) - _FOOTER_B
    if footer_at < len(MAGIC):
        return False
    handle.seek(footer_at)
    raw = handle.read(_FOOTER_B)
    opcode, length, summary_start, _, crc = struct.unpack('<BQQQI', raw)
    if opcode != Opcode.FOOTER or length != _FOOTER_B - _PREFIX_B:
        return False
    if summary_start == 0 or crc == 0:
        return True
    if summary_start > footer_at:
        return False
    handle.seek(summary_start)
    value = 0
    remaining = footer_at - summary_start
    while remaining:
        part = handle.read(min(remaining, 1 << 20))
        if not part:
            return False
        value = zlib.crc32(part, value)
        remaining -= len(part)
    return zlib.crc32(raw[:-4], value) == crc


def data_section_crc_ok(handle: BinaryIO) -> Optional[bool]:
    """
    Check the CRC of an MCAP file's data section (header, chunks and indexes) if it has one.

    Parameters
    ----------
    handle : file
        The file, opened for binary reading.

    Returns
    -------
    bool or None
        Whether the data section matches the CRC in its DataEnd record (False also when
        there is no DataEnd record before the summary); None if the file has no footer, no
        summary or no data section CRC.
    """
    size = handle.seek(0, os.SEEK_END)
    footer_at = size - len(MAGIC) - _FOOTER_B
    if footer_at < len(MAGIC):
        return None
    handle.seek(footer_at)
    opcode, _, summary_start, _, _ = struct.unpack('<BQQQI', handle.read(_FOOTER_B))
    data_end_at = summary_start - _DATA_END_B
    if opcode != Opcode.FOOTER or summary_start == 0 or not (
            len(MAGIC) <= data_end_at <= footer_at - _DATA_END_B):
        return None
    handle.seek(data_end_at)
    opcode, length, crc = struct.unpack('<BQI', handle.read(_DATA_END_B))
    if opcode != Opcode.DATA_END or length != 4:
        return False                    # the record before the summary is always DataEnd
    if crc == 0:
        return None
    handle.seek(0)
    value = 0
    remaining = data_end_at
    while remaining:
        part = handle.read(min(remaining, 1 << 20))
        if not part:
            return False
        value = zlib.crc32(part, value)
        remaining -= len(part)
    return value == crc


def read_header(handle: BinaryIO) -> Optional[Header]:
    """
    The Header record of an MCAP file.

    Parameters
    ----------
    handle : file
        The file, opened for binary reading.

    Returns
    -------
    mcap.records.Header or None
        None if the first record is not a readable header.
    """
    try:
        record = _read_at(handle, len(MAGIC), 0)
    except Exception:  # a damaged header
        return None
    return record if isinstance(record, Header) else None


def _read_at(handle: BinaryIO, offset: int, length: int) -> Optional[McapRecord]:
    handle.seek(offset)
    prefix = handle.read(_PREFIX_B)
    if len(prefix) < _PREFIX_B:
        raise ValueError(f'truncated record at byte {offset}')
    opcode, body_length = struct.unpack('<BQ', prefix)
    if length and body_length != length - _PREFIX_B:
        raise ValueError(f'record at byte {offset} is {body_length + _PREFIX_B} B, the index '
                         f'says {length} B')
    if body_length > 1 << 34:
        raise ValueError(f'implausible record length {body_length} B at byte {offset}')
    body = handle.read(body_length)
    if len(body) < body_length:
        raise ValueError(f'truncated record at byte {offset}')
    parser = _PARSERS.get(opcode)
    return parser(ReadDataStream(BytesIO(body))) if parser is not None else None


def _chunk_times(body: bytes) -> Tuple[Optional[int], Optional[int]]:
    """The (start, end) log times in a chunk record's header, if it is long enough."""
    if len(body) < 16:
        return None, None
    start, end = struct.unpack_from('<QQ', body)
    return (start, end) if start <= end else (None, None)


def _describe(exc: Exception) -> str:
    text = ' '.join(str(exc).split())
    return f'{type(exc).__name__}: {text}' if text else type(exc).__name__


def scan_bag(bag: Path, names: List[str]) -> List[ChunkDamage]:
    """
    Check every chunk of a bag's storage files (CRCs included), decoding no message.

    Parameters
    ----------
    bag : pathlib.Path
        The bag folder.
    names : list of str
        Its storage files.

    Returns
    -------
    list of ChunkDamage
        The damaged chunks (empty for an intact bag).
    """
    damage: List[ChunkDamage] = []
    for name in names:
        scan = McapScan(bag / name, name, expand=False)
        for _ in scan.records():
            pass
        damage.extend(scan.damage)
    return damage


__all__ = ['ChunkDamage', 'data_section_crc_ok', 'MAGIC', 'McapScan', 'read_header',
           'read_summary', 'scan_bag']
