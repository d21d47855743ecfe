"""
Read a recorded bag back to numpy: block streams as arrays, other topics as messages.

:func:`read_streams` assembles each block stream (``std_msgs/Float64MultiArray`` in the block
convention of :mod:`emfc_ros.core.blocks`) into one ``(channels, n)`` array in sample-index
order, with names and units from the latched ``<topic>/description`` messages. Missing
samples are never stitched over: by default a gap raises :class:`StreamGapError`; with
``on_gap='nan'`` the missing samples are NaN and listed in :attr:`Stream.gaps`.

A damaged storage file (a chunk whose CRC does not match, say after a flipped bit on disk)
stops rosbags; the reader then reads the file again chunk by chunk
(:mod:`emfc_ros.core.bag.scan`), skips the corrupt chunks and returns everything else. Each
skipped chunk is a :class:`~emfc_ros.core.bag.scan.ChunkDamage` (file, byte offset, time range,
messages lost) in :attr:`Stream.damage` of the streams it held, and a
:class:`BagDamageWarning` is issued; the blocks it held are missing samples like any other
gap (raised by default, NaN with ``on_gap='nan'``), never joined over.

:func:`read_messages` yields any topic's messages deserialised (rosbags, pinned Jazzy
typestore), for example ``sensor_msgs/JointState`` or ``diagnostic_msgs/DiagnosticArray``.

No ROS installation is needed: reading uses rosbags only.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Dict, Iterable, Iterator, List, Optional, Sequence, Tuple
import warnings

from mcap.records import Channel, Message
import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader
from rosbags.typesys import get_typestore, Stores

from emfc_ros.core.bag.cdr import decode_block
from emfc_ros.core.bag.errors import BagFormatError, StreamGapError
from emfc_ros.core.bag.metadata import METADATA_FILE, read_metadata
from emfc_ros.core.bag.scan import ChunkDamage, McapScan
from emfc_ros.core.blocks import StreamDescription
from emfc_ros.core.errors import BlockError, EmfcError

BLOCK_TYPE = 'std_msgs/msg/Float64MultiArray'
DESCRIPTION_TYPE = 'std_msgs/msg/String'
DESCRIPTION_SUFFIX = '/description'
ON_GAP = ('raise', 'nan')


class BagDamageWarning(UserWarning):
    """A bag had corrupt chunks: what they held was skipped (see the damage reports)."""


class _SourceError(EmfcError, RuntimeError):
    """The message source (rosbags) failed while reading: read the files chunk by chunk."""


@dataclasses.dataclass
class Stream:
    """
    One recorded block stream (one topic, one epoch) as arrays.

    Attributes
    ----------
    topic : str
        The topic it was recorded from.
    stream : str
        Stream name from the description (the topic's base name without one).
    epoch : int
        Stream epoch.
    sample_rate_Hz : float
        Sample clock rate [Hz].
    first_sample_index : int
        Index of ``samples[:, 0]`` on the stream's sample clock.
    samples : numpy.ndarray
        Shape ``(channels, n)``, float64, in sample-index order; NaN in gaps when
        ``on_gap='nan'``.
    channel_names : tuple of str
        From the description (``ch0``, ``ch1``... without one).
    channel_units : tuple of str
        SI unit symbols ('' without a description).
    gaps : list of tuple
        ``(first_missing_index, n_missing)`` for each run of missing samples.
    duplicates : int
        Blocks recorded twice (identical; ignored).
    block_first_index : numpy.ndarray
        First sample index of each block, in sample order.
    block_receive_time_ns : numpy.ndarray
        Receive (bag) timestamp of each block [ns], same order.
    description : StreamDescription or None
        The matching description, if one was recorded.
    damage : list of ChunkDamage
        Corrupt chunks of the bag that held (or may have held) blocks of this stream; their
        blocks are missing (gaps when inside the stream).
    """

    topic: str
    stream: str
    epoch: int
    sample_rate_Hz: float
    first_sample_index: int
    samples: np.ndarray
    channel_names: Tuple[str, ...]
    channel_units: Tuple[str, ...]
    gaps: List[Tuple[int, int]]
    duplicates: int
    block_first_index: np.ndarray
    block_receive_time_ns: np.ndarray
    description: Optional[StreamDescription] = None
    damage: List[ChunkDamage] = dataclasses.field(default_factory=list)

    @property
    def n_samples(self) -> int:
        """
        Samples per channel (gaps included).

        Returns
        -------
        int
            ``samples.shape[1]``.
        """
        return int(self.samples.shape[1])

    @property
    def sample_index(self) -> np.ndarray:
        """
        The sample-clock index of every column of :attr:`samples`.

        Returns
        -------
        numpy.ndarray
            int64, ``first_sample_index + arange(n)``.
        """
        return self.first_sample_index + np.arange(self.n_samples, dtype=np.int64)

    @property
    def time_s(self) -> np.ndarray:
        """
        Sample times after the stream's sample 0 [s].

        Returns
        -------
        numpy.ndarray
            ``sample_index / sample_rate_Hz``.
        """
        return self.sample_index / self.sample_rate_Hz

    @property
    def missing_samples(self) -> int:
        """
        Samples missing in gaps.

        Returns
        -------
        int
            Sum of the gap lengths.
        """
        return sum(n for _, n in self.gaps)

    def channel(self, name: str) -> np.ndarray:
        """
        One channel's samples.

        Parameters
        ----------
        name : str
            Channel name.

        Returns
        -------
        numpy.ndarray
            Shape ``(n,)``.

        Raises
        ------
        KeyError
            If there is no such channel.
        """
        if name not in self.channel_names:
            raise KeyError(f'{self.topic} has no channel {name!r}; channels are '
                           f'{list(self.channel_names)}')
        return self.samples[self.channel_names.index(name)]


def _check_metadata(bag_path) -> None:
    """Refuse a hostile metadata.yaml before rosbags parses it (emfc_ros.core.safe_yaml)."""
    if (Path(bag_path) / METADATA_FILE).is_file():
        read_metadata(Path(bag_path))


def open_reader(bag_path) -> Reader:
    """
    Open a bag with rosbags' rosbag2 reader, with a helpful error for damaged bags.

    Parameters
    ----------
    bag_path : str or pathlib.Path
        The bag folder.

    Returns
    -------
    rosbags.rosbag2.Reader
        An opened reader (close it, or use it as a context manager).

    Raises
    ------
    BagFormatError
        If the bag cannot be opened (run ``emfc-bag-repair`` on a bag whose recorder died).
    """
    _check_metadata(bag_path)
    try:
        reader = Reader(Path(bag_path))
        reader.open()
    except Exception as exc:  # rosbags raises several unrelated types
        raise BagFormatError(f'cannot open bag {bag_path}: {exc}; if the recorder was '
                             f'killed, run `emfc-bag-repair {bag_path}` first') from exc
    return reader


def read_streams(bag_path, topics: Optional[Sequence[str]] = None,
                 on_gap: str = 'raise') -> Dict[str, Stream]:
    """
    Read every block stream of a bag (or the given topics) into arrays.

    Parameters
    ----------
    bag_path : str or pathlib.Path
        The bag folder.
    topics : sequence of str, optional
        Block topics to read; all ``Float64MultiArray`` topics that follow the block
        convention when absent.
    on_gap : str
        ``'raise'``: a gap raises :class:`StreamGapError`; ``'nan'``: missing samples are
        NaN and listed in :attr:`Stream.gaps`.

    Returns
    -------
    dict
        Topic name to :class:`Stream`; a topic recorded in several epochs gives one entry
        per epoch, keyed ``'<topic>#<epoch>'``.

    Raises
    ------
    StreamGapError
        If a stream has missing samples, or blocks in a corrupt chunk, and
        ``on_gap='raise'``.
    BlockError
        If a named topic is not a block stream or blocks overlap inconsistently.
    BagFormatError
        If the bag cannot be opened or read (a damaged file without its summary).

    Warns
    -----
    BagDamageWarning
        If corrupt chunks were skipped.
    """
    if on_gap not in ON_GAP:
        raise ValueError(f'on_gap must be one of {list(ON_GAP)}, got {on_gap!r}')
    reader = open_reader(bag_path)
    try:
        by_topic = {c.topic: c for c in reader.connections}
        wanted = list(topics) if topics is not None else sorted(
            c.topic for c in reader.connections if c.msgtype == BLOCK_TYPE)
        for topic in wanted:
            conn = by_topic.get(topic)
            if conn is None or conn.msgtype != BLOCK_TYPE:
                raise BlockError(f'{topic} is not a {BLOCK_TYPE} topic of {bag_path}')
        desc_topics = {t + DESCRIPTION_SUFFIX for t in wanted
                       if by_topic.get(t + DESCRIPTION_SUFFIX) is not None
                       and by_topic[t + DESCRIPTION_SUFFIX].msgtype == DESCRIPTION_TYPE}
        conns = [by_topic[t] for t in sorted(desc_topics)] + [by_topic[t] for t in wanted]
        # rosbags reads every topic when given no connection: guard the empty case.
        source = ((c.topic, t, raw) for c, t, raw in reader.messages(connections=conns)) \
            if conns else iter(())
        damage: List[ChunkDamage] = []
        try:
            collected = _collect(_guarded(source), wanted, desc_topics, topics is not None)
        except _SourceError as exc:
            damage, messages = _scan_messages(Path(bag_path), set(wanted) | desc_topics, exc)
            collected = _collect(messages, wanted, desc_topics, topics is not None)
    finally:
        reader.close()
    descriptions, raw_blocks, skipped = collected
    if damage:
        warnings.warn(BagDamageWarning(
            f'{bag_path}: {len(damage)} corrupt chunks skipped: '
            + '; '.join(d.describe() for d in damage)), stacklevel=2)
    out: Dict[str, Stream] = {}
    for topic in wanted:
        if topic in skipped or not raw_blocks[topic]:
            continue
        hit = [d for d in damage if not d.topics or topic in d.topics]
        epochs = sorted({b.epoch for b, _ in raw_blocks[topic]})
        for epoch in epochs:
            chosen = [(b, t) for b, t in raw_blocks[topic] if b.epoch == epoch]
            described = [d for d in descriptions.get(topic, []) if d.epoch == epoch]
            key = topic if len(epochs) == 1 else f'{topic}#{epoch}'
            out[key] = _assemble(topic, epoch, chosen, described[-1] if described else None,
                                 on_gap, hit)
    return out


def _guarded(source: Iterator[tuple]) -> Iterator[tuple]:
    """Yield from ``source``, turning any error it raises into :class:`_SourceError`."""
    while True:
        try:
            item = next(source)
        except StopIteration:
            return
        except Exception as exc:  # rosbags raises several unrelated types
            raise _SourceError(f'{type(exc).__name__}: {exc}') from exc
        yield item


def _scan_messages(bag: Path, topics: set, exc: Exception
                   ) -> Tuple[List[ChunkDamage], List[tuple]]:
    """Every readable message of the given topics, file by file, and the damage found."""
    from emfc_ros.core.bag.repair import storage_files
    damage: List[ChunkDamage] = []
    messages: List[tuple] = []
    for name in storage_files(bag):
        scan = McapScan(bag / name, name)
        channels: Dict[int, str] = {}
        for record in scan.records():
            if isinstance(record, Channel):
                channels[record.id] = record.topic
            elif isinstance(record, Message) and channels.get(record.channel_id) in topics:
                messages.append((channels[record.channel_id], record.log_time, record.data))
        damage.extend(scan.damage)
        if scan.error and not scan.complete:
            raise BagFormatError(f'cannot read {bag / name}: {scan.error}; run '
                                 f'`emfc-bag-repair {bag}` first') from exc
    if not damage:
        raise BagFormatError(f'cannot read {bag}: {exc}') from exc
    return damage, messages


def _collect(source: Iterable[tuple], wanted: List[str], desc_topics: set,
             explicit: bool) -> tuple:
    """Decode descriptions and blocks from ``(topic, timestamp, raw)`` messages."""
    typestore = get_typestore(Stores.ROS2_JAZZY)
    descriptions: Dict[str, List[StreamDescription]] = {}
    raw_blocks: Dict[str, list] = {t: [] for t in wanted}
    skipped = set()
    for topic, timestamp, raw in source:
        if topic in desc_topics:
            # rosbags makes the message classes at run time: its type says object
            message: Any = typestore.deserialize_cdr(raw, DESCRIPTION_TYPE)
            text = message.data
            try:
                descriptions.setdefault(topic[:-len(DESCRIPTION_SUFFIX)], []).append(
                    StreamDescription.from_json(text))
            except BlockError:
                pass
            continue
        if topic in skipped or topic not in raw_blocks:
            continue
        try:
            block = decode_block(raw)
        except BlockError:
            if explicit:
                raise
            skipped.add(topic)
            continue
        raw_blocks[topic].append((block, timestamp))
    return descriptions, raw_blocks, skipped


def _assemble(topic: str, epoch: int, chosen: list,
              description: Optional[StreamDescription], on_gap: str,
              damage: List[ChunkDamage]) -> Stream:
    chosen.sort(key=lambda bt: bt[0].first_sample_index)
    n_channels = chosen[0][0].samples.shape[0]
    rate = chosen[0][0].sample_rate_Hz
    kept: list = []
    duplicates = 0
    gaps: List[Tuple[int, int]] = []
    expected = chosen[0][0].first_sample_index
    for block, timestamp in chosen:
        if block.samples.shape[0] != n_channels:
            raise BlockError(f'{topic} epoch {epoch}: block at {block.first_sample_index} '
                             f'has {block.samples.shape[0]} channels, not {n_channels}')
        if block.sample_rate_Hz != rate:
            raise BlockError(f'{topic} epoch {epoch}: sample rate changes from {rate} to '
                             f'{block.sample_rate_Hz} Hz')
        if block.first_sample_index < expected:
            prev = kept[-1][0]
            if (block.first_sample_index == prev.first_sample_index
                    and np.array_equal(block.samples, prev.samples)):
                duplicates += 1
                continue
            raise BlockError(f'{topic} epoch {epoch}: block at {block.first_sample_index} '
                             f'overlaps the samples before {expected} with other values')
        if block.first_sample_index > expected:
            gaps.append((expected, block.first_sample_index - expected))
        kept.append((block, timestamp))
        expected = block.end_index
    first = kept[0][0].first_sample_index
    if damage and on_gap == 'raise':
        missing = sum(n for _, n in gaps)
        raise StreamGapError(
            f'{topic} epoch {epoch}: the bag has {len(damage)} corrupt chunks ('
            + '; '.join(d.describe() for d in damage) + f'); {missing} samples missing in '
            f'{len(gaps)} gaps; use on_gap="nan" to read the rest with NaN in the gaps, or '
            f'`emfc-bag-repair` to rebuild the bag without them')
    if gaps and on_gap == 'raise':
        missing = sum(n for _, n in gaps)
        raise StreamGapError(
            f'{topic} epoch {epoch}: {missing} samples missing in {len(gaps)} gaps, the first '
            f'at sample {gaps[0][0]}; use on_gap="nan" to read it with NaN in the gaps')
    samples = np.full((n_channels, expected - first), np.nan) if gaps else np.empty(
        (n_channels, expected - first))
    for block, _ in kept:
        start = block.first_sample_index - first
        samples[:, start:start + block.n_samples] = block.samples
    if description is not None and len(description.channels) == n_channels:
        names = description.channel_names
        units = tuple(c.unit for c in description.channels)
        stream = description.stream
    else:
        names = tuple(f'ch{i}' for i in range(n_channels))
        units = ('',) * n_channels
        stream = topic.rsplit('/', 1)[-1]
        description = None
    return Stream(topic=topic, stream=stream, epoch=epoch, sample_rate_Hz=rate,
                  first_sample_index=first, samples=samples, channel_names=names,
                  channel_units=units, gaps=gaps, duplicates=duplicates,
                  block_first_index=np.array([b.first_sample_index for b, _ in kept],
                                             dtype=np.int64),
                  block_receive_time_ns=np.array([t for _, t in kept], dtype=np.int64),
                  description=description, damage=list(damage))


def read_messages(bag_path, topic: str) -> Iterator[Tuple[int, object]]:
    """
    Yield a topic's messages, deserialised, in timestamp order.

    Parameters
    ----------
    bag_path : str or pathlib.Path
        The bag folder.
    topic : str
        The topic.

    Yields
    ------
    tuple
        ``(timestamp_ns, message)``; messages are rosbags dataclasses with the ROS fields.

    Raises
    ------
    KeyError
        If the bag has no such topic.
    BagFormatError
        If the bag cannot be opened or read.

    Warns
    -----
    BagDamageWarning
        If corrupt chunks were skipped (their messages are not yielded).
    """
    typestore = get_typestore(Stores.ROS2_JAZZY)
    _check_metadata(bag_path)
    try:
        reader = AnyReader([Path(bag_path)], default_typestore=typestore)
        reader.open()
    except Exception as exc:  # rosbags raises several unrelated types
        raise BagFormatError(f'cannot open bag {bag_path}: {exc}; if the recorder was '
                             f'killed, run `emfc-bag-repair {bag_path}` first') from exc
    try:
        conns = [c for c in reader.connections if c.topic == topic]
        if not conns:
            raise KeyError(f'{bag_path} has no topic {topic!r}; topics are '
                           f'{sorted({c.topic for c in reader.connections})}')
        # the last timestamp yielded, and its messages
        last: Tuple[Optional[int], List[bytes]] = (None, [])
        try:
            for conn, timestamp, raw in _guarded(reader.messages(connections=conns)):
                yield timestamp, reader.deserialize(raw, conn.msgtype)
                last = (timestamp, last[1] + [raw]) if timestamp == last[0] else (
                    timestamp, [raw])
        except _SourceError as exc:
            # A corrupt chunk: go on from where rosbags stopped, skipping the bad chunks.
            damage, messages = _scan_messages(Path(bag_path), {topic}, exc)
            warnings.warn(BagDamageWarning(
                f'{bag_path}: {len(damage)} corrupt chunks skipped: '
                + '; '.join(d.describe() for d in damage)), stacklevel=2)
            for _, timestamp, raw in sorted(messages, key=lambda m: m[1]):
                if last[0] is not None and (timestamp < last[0] or (
                        timestamp == last[0] and raw in last[1])):
                    continue
                yield timestamp, reader.deserialize(raw, conns[0].msgtype)
    finally:
        reader.close()
