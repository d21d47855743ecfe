"""
Read a recorded bag back to numpy: block streams as arrays, other topics as messages.

:func:`read_streams` assembles each block stream (``std_msgs/Float64MultiArray`` in the block
convention of :mod:`emfc_ros.core.blocks`) into one ``(channels, n)`` array in sample-index
order, with names and units from the latched ``<topic>/description`` messages. Missing
samples are never stitched over: by default a gap raises :class:`StreamGapError`; with
``on_gap='nan'`` the missing samples are NaN and listed in :attr:`Stream.gaps`.

:func:`read_messages` yields any topic's messages deserialised (rosbags, pinned Jazzy
typestore), for example ``sensor_msgs/JointState`` or ``diagnostic_msgs/DiagnosticArray``.

No ROS installation is needed: reading uses rosbags only.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Dict, Iterator, List, Optional, Sequence, Tuple

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader
from rosbags.typesys import get_typestore, Stores

from emfc_ros.core.bag.cdr import decode_block
from emfc_ros.core.bag.errors import BagFormatError, StreamGapError
from emfc_ros.core.blocks import StreamDescription
from emfc_ros.core.errors import BlockError

BLOCK_TYPE = 'std_msgs/msg/Float64MultiArray'
DESCRIPTION_TYPE = 'std_msgs/msg/String'
DESCRIPTION_SUFFIX = '/description'
ON_GAP = ('raise', 'nan')


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
        If a stream has missing samples and ``on_gap='raise'``.
    BlockError
        If a named topic is not a block stream or blocks overlap inconsistently.
    BagFormatError
        If the bag cannot be opened.
    """
    if on_gap not in ON_GAP:
        raise ValueError(f'on_gap must be one of {list(ON_GAP)}, got {on_gap!r}')
    typestore = get_typestore(Stores.ROS2_JAZZY)
    reader = open_reader(bag_path)
    try:
        by_topic = {c.topic: c for c in reader.connections}
        wanted = list(topics) if topics is not None else sorted(
            c.topic for c in reader.connections if c.msgtype == BLOCK_TYPE)
        for topic in wanted:
            conn = by_topic.get(topic)
            if conn is None or conn.msgtype != BLOCK_TYPE:
                raise BlockError(f'{topic} is not a {BLOCK_TYPE} topic of {bag_path}')
        descriptions: Dict[str, List[StreamDescription]] = {}
        desc_conns = [by_topic[t + DESCRIPTION_SUFFIX] for t in wanted
                      if by_topic.get(t + DESCRIPTION_SUFFIX) is not None
                      and by_topic[t + DESCRIPTION_SUFFIX].msgtype == DESCRIPTION_TYPE]
        # rosbags reads every topic when given no connection: guard the empty cases.
        for conn, _, raw in reader.messages(connections=desc_conns) if desc_conns else ():
            text = typestore.deserialize_cdr(raw, DESCRIPTION_TYPE).data
            try:
                descriptions.setdefault(conn.topic[:-len(DESCRIPTION_SUFFIX)], []).append(
                    StreamDescription.from_json(text))
            except BlockError:
                continue
        raw_blocks: Dict[str, list] = {t: [] for t in wanted}
        explicit = topics is not None
        skipped = set()
        conns = [by_topic[t] for t in wanted]
        for conn, timestamp, raw in reader.messages(connections=conns) if conns else ():
            if conn.topic in skipped:
                continue
            try:
                block = decode_block(raw)
            except BlockError:
                if explicit:
                    raise
                skipped.add(conn.topic)
                continue
            raw_blocks[conn.topic].append((block, timestamp))
    finally:
        reader.close()
    out: Dict[str, Stream] = {}
    for topic in wanted:
        if topic in skipped or not raw_blocks[topic]:
            continue
        epochs = sorted({b.epoch for b, _ in raw_blocks[topic]})
        for epoch in epochs:
            chosen = [(b, t) for b, t in raw_blocks[topic] if b.epoch == epoch]
            described = [d for d in descriptions.get(topic, []) if d.epoch == epoch]
            key = topic if len(epochs) == 1 else f'{topic}#{epoch}'
            out[key] = _assemble(topic, epoch, chosen, described[-1] if described else None,
                                 on_gap)
    return out


def _assemble(topic: str, epoch: int, chosen: list,
              description: Optional[StreamDescription], on_gap: str) -> Stream:
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
                  description=description)


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
        If the bag cannot be opened.
    """
    typestore = get_typestore(Stores.ROS2_JAZZY)
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
        for conn, timestamp, raw in reader.messages(connections=conns):
            yield timestamp, reader.deserialize(raw, conn.msgtype)
    finally:
        reader.close()
