"""
The block convention: how multi-channel sample blocks travel as ``Float64MultiArray``.

A block carries ``C`` channels of ``N`` samples of one sample clock. Its flat ``data`` is::

    data[0:H]          header, H = data_offset = HEADER_LENGTH
    data[H:H + C*N]    samples, channel-major: channel c, sample n at H + c*N + n

Header fields (float64, integers are exact below 2**53):

    0  first_sample_index   index of the block's first sample on the stream's sample clock
    1  sample_rate_Hz       the sample clock's rate [Hz]
    2  epoch                stream epoch: incremented each time the stream restarts at 0

The layout has two dimensions: ``dim[0]`` label ``'channel'``, size ``C``, stride ``C*N``;
``dim[1]`` label ``'sample'``, size ``N``, stride ``N``; ``data_offset = H``. Channel names
and units travel on the latched description topic (:class:`StreamDescription`, JSON in a
``std_msgs/String``). Sample ``n`` of a block is at time ``(first_sample_index + n) /
sample_rate_Hz`` after the stream's start time.

This module is pure: the message conversion lives in :mod:`emfc_ros.nodes.convert`.
"""

from __future__ import annotations

import collections
import dataclasses
import enum
import json
from typing import Any, Optional, Sequence, Tuple

import numpy as np

from emfc_ros.core.errors import BlockError
from emfc_ros.core.json_text import load_json_text

CONVENTION = 'emfc_ros/block/1'
HEADER_FIELDS = ('first_sample_index', 'sample_rate_Hz', 'epoch')
HEADER_LENGTH = len(HEADER_FIELDS)
CHANNEL_LABEL = 'channel'
SAMPLE_LABEL = 'sample'
MAX_EXACT_INDEX = 2 ** 53
#: Most samples per channel in one block (the nodes' ``block_size`` limit too): a larger
#: block is refused before anything is copied or simulated.
MAX_BLOCK_SAMPLES = 1_000_000
#: Most channels in one block.
MAX_BLOCK_CHANNELS = 256


@dataclasses.dataclass(frozen=True)
class Channel:
    """
    One channel of a stream.

    Attributes
    ----------
    name : str
        Channel name, for example ``'coil_setpoint'``.
    unit : str
        SI unit symbol of the values, for example ``'V'``, ``'A'``, ``'m'``, ``'N'``.
    description : str
        Free text for people.
    """

    name: str
    unit: str
    description: str = ''


@dataclasses.dataclass(frozen=True)
class StreamDescription:
    """
    What a receiver needs to interpret the blocks of one stream.

    Attributes
    ----------
    stream : str
        Stream name (usually the topic's base name).
    sample_rate_Hz : float
        Sample clock rate [Hz].
    block_size : int
        Nominal samples per block (a final block may be shorter).
    channels : tuple of Channel
        The channels, in block order.
    epoch : int
        Current stream epoch (see the module docstring).
    start_time_ns : int
        Time of sample 0 of this epoch on the publisher's clock [ns] (0 if unknown).
    total_samples : int
        Samples the stream will carry in this epoch, or -1 if open-ended.
    source : str
        Which node or device produced it.
    extra : dict
        Anything else (for example the section table of an experiment).
    """

    stream: str
    sample_rate_Hz: float
    block_size: int
    channels: Tuple[Channel, ...]
    epoch: int = 0
    start_time_ns: int = 0
    total_samples: int = -1
    source: str = ''
    extra: dict = dataclasses.field(default_factory=dict)

    @property
    def channel_names(self) -> Tuple[str, ...]:
        """
        Channel names in block order.

        Returns
        -------
        tuple of str
            The names.
        """
        return tuple(c.name for c in self.channels)

    def to_json(self) -> str:
        """
        Serialise for the description topic.

        Returns
        -------
        str
            A JSON document with a ``convention`` field naming this convention.
        """
        doc = dataclasses.asdict(self)
        doc['convention'] = CONVENTION
        doc['header_fields'] = list(HEADER_FIELDS)
        doc['layout'] = 'channel-major'
        return json.dumps(doc, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> 'StreamDescription':
        """
        Parse a description published by :meth:`to_json`.

        Parameters
        ----------
        text : str
            The JSON document.

        Returns
        -------
        StreamDescription
            The description.

        Raises
        ------
        BlockError
            If the document is not a description of this convention, malformed, larger than
            4 MiB or nested more than 64 levels deep (never another exception).
        """
        try:
            doc = load_json_text(text, 'stream description')
            if not isinstance(doc, dict):
                raise BlockError(f'a stream description is a JSON object, got '
                                 f'{type(doc).__name__}')
            if doc.get('convention') != CONVENTION:
                raise BlockError(
                    f'description convention {doc.get("convention")!r} is not {CONVENTION!r}')
            channels = tuple(Channel(**c) for c in doc['channels'])
            return cls(stream=str(doc['stream']), sample_rate_Hz=float(doc['sample_rate_Hz']),
                       block_size=int(doc['block_size']), channels=channels,
                       epoch=int(doc.get('epoch', 0)),
                       start_time_ns=int(doc.get('start_time_ns', 0)),
                       total_samples=int(doc.get('total_samples', -1)),
                       source=str(doc.get('source', '')), extra=dict(doc.get('extra', {})))
        except BlockError:
            raise
        except (ValueError, KeyError, TypeError, AttributeError, RecursionError) as exc:
            raise BlockError(f'malformed stream description: {exc}') from None


@dataclasses.dataclass(frozen=True)
class Block:
    """
    One block of samples.

    Attributes
    ----------
    first_sample_index : int
        Index of ``samples[:, 0]`` on the stream's sample clock.
    sample_rate_Hz : float
        Sample clock rate [Hz].
    epoch : int
        Stream epoch.
    samples : numpy.ndarray
        Shape ``(channels, n)``, float64.
    """

    first_sample_index: int
    sample_rate_Hz: float
    epoch: int
    samples: np.ndarray

    @property
    def n_samples(self) -> int:
        """
        Samples per channel in this block.

        Returns
        -------
        int
            ``samples.shape[1]``.
        """
        return int(self.samples.shape[1])

    @property
    def end_index(self) -> int:
        """
        Index one past the block's last sample.

        Returns
        -------
        int
            ``first_sample_index + n_samples``.
        """
        return self.first_sample_index + self.n_samples


def pack_into(buffer: np.ndarray, first_sample_index: int, sample_rate_Hz: float,
              epoch: int, samples: np.ndarray) -> np.ndarray:
    """
    Write header and samples into a flat float64 buffer (no allocation).

    Parameters
    ----------
    buffer : numpy.ndarray
        Flat float64 array of at least ``HEADER_LENGTH + samples.size`` elements.
    first_sample_index : int
        Index of the first sample.
    sample_rate_Hz : float
        Sample rate [Hz].
    epoch : int
        Stream epoch.
    samples : numpy.ndarray
        Shape ``(channels, n)``.

    Returns
    -------
    numpy.ndarray
        The used part of ``buffer``.

    Raises
    ------
    BlockError
        If the index is negative or too large to be exact, or the buffer is too small.
    """
    if samples.ndim != 2:
        raise BlockError(f'samples must be 2-D (channels, n), got shape {samples.shape}')
    if not 0 <= first_sample_index < MAX_EXACT_INDEX:
        raise BlockError(f'first_sample_index {first_sample_index} outside [0, 2**53)')
    used = HEADER_LENGTH + samples.size
    if buffer.size < used:
        raise BlockError(f'buffer of {buffer.size} values cannot hold {used}')
    out = buffer[:used]
    out[0] = first_sample_index
    out[1] = sample_rate_Hz
    out[2] = epoch
    out[HEADER_LENGTH:].reshape(samples.shape)[...] = samples
    return out


def pack(first_sample_index: int, sample_rate_Hz: float, epoch: int,
         samples: np.ndarray) -> np.ndarray:
    """
    Build the flat ``data`` array of a block.

    Parameters
    ----------
    first_sample_index : int
        Index of the first sample.
    sample_rate_Hz : float
        Sample rate [Hz].
    epoch : int
        Stream epoch.
    samples : numpy.ndarray
        Shape ``(channels, n)``.

    Returns
    -------
    numpy.ndarray
        Flat float64 array of ``HEADER_LENGTH + channels * n`` values.
    """
    samples = np.asarray(samples, dtype=np.float64)
    buffer = np.empty(HEADER_LENGTH + samples.size, dtype=np.float64)
    return pack_into(buffer, first_sample_index, sample_rate_Hz, epoch, samples)


def layout(n_channels: int, n_samples: int) -> Sequence[Tuple[str, int, int]]:
    """
    The layout dimensions of a block as (label, size, stride) triples.

    Parameters
    ----------
    n_channels : int
        Channels in the block.
    n_samples : int
        Samples per channel.

    Returns
    -------
    list of tuple
        ``[('channel', C, C*N), ('sample', N, N)]``.
    """
    return [(CHANNEL_LABEL, n_channels, n_channels * n_samples),
            (SAMPLE_LABEL, n_samples, n_samples)]


def unpack(dims: Sequence[Tuple[str, int, int]], data_offset: int, data: Any,
           expected_channels: Optional[int] = None) -> Block:
    """
    Check and decode a block.

    Parameters
    ----------
    dims : sequence of (label, size, stride)
        The layout dimensions.
    data_offset : int
        The layout's data offset (the header length).
    data : buffer-like
        The flat float64 data (``array.array``, ``numpy.ndarray``, list...).
    expected_channels : int, optional
        Refuse blocks with another channel count.

    Returns
    -------
    Block
        The block; ``samples`` is a read-only view when ``data`` supports the buffer protocol.

    Raises
    ------
    BlockError
        If the layout, header or size does not follow the convention.
    """
    if len(dims) != 2:
        raise BlockError(f'expected 2 layout dimensions, got {len(dims)}')
    (lab0, n_ch, stride0), (lab1, n_s, stride1) = dims
    if lab0 != CHANNEL_LABEL or lab1 != SAMPLE_LABEL:
        raise BlockError(f'layout labels {lab0!r}, {lab1!r} are not '
                         f'{CHANNEL_LABEL!r}, {SAMPLE_LABEL!r}')
    if stride0 != n_ch * n_s or stride1 != n_s:
        raise BlockError(f'layout strides {stride0}, {stride1} do not match sizes '
                         f'{n_ch} x {n_s}')
    if data_offset != HEADER_LENGTH:
        raise BlockError(f'data_offset {data_offset} is not the header length {HEADER_LENGTH}')
    if not 0 <= n_s <= MAX_BLOCK_SAMPLES or not 0 <= n_ch <= MAX_BLOCK_CHANNELS:
        raise BlockError(f'block of {n_ch} channels x {n_s} samples exceeds the maximum '
                         f'{MAX_BLOCK_CHANNELS} x {MAX_BLOCK_SAMPLES}')
    if expected_channels is not None and n_ch != expected_channels:
        raise BlockError(f'block has {n_ch} channels, expected {expected_channels}')
    try:
        flat = np.frombuffer(data, dtype=np.float64)
    except (TypeError, ValueError):
        flat = np.asarray(data, dtype=np.float64)
    if flat.size != HEADER_LENGTH + n_ch * n_s:
        raise BlockError(f'data holds {flat.size} values, layout needs '
                         f'{HEADER_LENGTH + n_ch * n_s}')
    first, rate, epoch = flat[0], flat[1], flat[2]
    if not (np.isfinite(first) and first >= 0 and first < MAX_EXACT_INDEX
            and float(first).is_integer()):
        raise BlockError(f'header first_sample_index {first!r} is not a valid index')
    if not (np.isfinite(rate) and rate > 0):
        raise BlockError(f'header sample_rate_Hz {rate!r} is not positive')
    if not (np.isfinite(epoch) and float(epoch).is_integer()):
        raise BlockError(f'header epoch {epoch!r} is not an integer')
    samples = flat[HEADER_LENGTH:].reshape(n_ch, n_s)
    return Block(int(first), float(rate), int(epoch), samples)


class Continuity(enum.Enum):
    """How a received block relates to the stream so far."""

    FIRST = 'first'
    CONTIGUOUS = 'contiguous'
    GAP = 'gap'
    DUPLICATE = 'duplicate'
    REORDERED = 'reordered'
    OVERLAP = 'overlap'
    RESTART = 'restart'


class SequenceTracker:
    """
    Classify incoming blocks of one stream and count defects; never hides one.

    A block is CONTIGUOUS when it starts where the previous one ended; GAP when it starts
    later (the missing samples are counted); DUPLICATE when it starts where one of the last
    256 blocks started; REORDERED when it ends at or before the last block's start (a late
    block); OVERLAP when it starts earlier than expected but overlaps the last block;
    RESTART when the epoch changes (the index may restart at 0).
    """

    def __init__(self) -> None:
        self.expected: Optional[int] = None
        self.epoch: Optional[int] = None
        self.blocks = 0
        self.gaps = 0
        self.missing_samples = 0
        self.duplicates = 0
        self.reordered = 0
        self.overlaps = 0
        self.restarts = 0
        self._recent: collections.deque = collections.deque(maxlen=256)

    def observe(self, first_sample_index: int, n_samples: int, epoch: int = 0) -> Continuity:
        """
        Record one block and say how it continues the stream.

        Parameters
        ----------
        first_sample_index : int
            The block's first index.
        n_samples : int
            Its length.
        epoch : int
            Its stream epoch.

        Returns
        -------
        Continuity
            The classification; counters are updated.
        """
        self.blocks += 1
        end = first_sample_index + n_samples
        if self.expected is None or epoch != self.epoch:
            kind = Continuity.FIRST if self.expected is None else Continuity.RESTART
            if kind is Continuity.RESTART:
                self.restarts += 1
            self.epoch = epoch
            self.expected = end
            self._recent.clear()
            self._recent.append(first_sample_index)
            return kind
        if first_sample_index == self.expected:
            kind = Continuity.CONTIGUOUS
        elif first_sample_index > self.expected:
            self.gaps += 1
            self.missing_samples += first_sample_index - self.expected
            kind = Continuity.GAP
        elif first_sample_index in self._recent:
            self.duplicates += 1
            return Continuity.DUPLICATE
        elif end <= self._recent[-1]:
            self.reordered += 1
            self._recent.append(first_sample_index)
            return Continuity.REORDERED
        else:
            self.overlaps += 1
            return Continuity.OVERLAP
        self.expected = end
        self._recent.append(first_sample_index)
        return kind

    def counters(self) -> dict:
        """
        The defect counters.

        Returns
        -------
        dict
            Blocks seen, gaps, missing samples, duplicates, reordered, overlaps, restarts.
        """
        return {'blocks': self.blocks, 'gaps': self.gaps,
                'missing_samples': self.missing_samples, 'duplicates': self.duplicates,
                'reordered': self.reordered, 'overlaps': self.overlaps,
                'restarts': self.restarts}
