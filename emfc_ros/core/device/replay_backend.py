"""
Back-end ``'replay'``: the measurements of a recorded bag, played back as a device would.

The blocks of one recorded block stream (by default the bag's ``measurements`` topic, read
with :func:`emfc_ros.core.bag.read_streams`) are returned by :meth:`ReplayBackend.read_block`
one recorded block at a time, with their recorded first sample indices (exact; a recorded gap
stays a jump of the index and is never stitched over), in SI units, paced:

- ``'receive_time'``: block ``i`` is due ``(t_i - t_0) / speed`` after START, ``t_i`` its
  recorded receive time (the original publication timing, jitter included);
- ``'sample_clock'``: block ``i`` is due when its last sample is,
  ``(end_i - first_0) / (sample_rate_Hz * speed)`` after START (as a device sends frames);
- ``'fast'``: as fast as the reader asks.

Setpoint writes and function-generator requests are accepted, counted and ignored (a bag has
no actuator). The configuration the bag implies (rate, block size, channel names and units)
is :attr:`ReplayBackend.recorded_config`; :meth:`ReplayBackend.configure` refuses another
sample rate or other channel names.
"""

from __future__ import annotations

import threading
import time
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple

import numpy as np

from emfc_ros.core.blocks import Block
from emfc_ros.core.device.backend import (DeviceConfig, InputChannel, MAX_BLOCK_SIZE,
                                          OutputChannel)
from emfc_ros.core.device.errors import DeviceConfigError, DeviceError
from emfc_ros.core.device.function_generator import GeneratorSpec

PACINGS = ('receive_time', 'sample_clock', 'fast')
DEFAULT_TOPIC_SUFFIX = 'measurements'


def _pick_stream(streams: Dict[str, object], topic: str, bag: str):
    if topic:
        chosen = [s for key, s in streams.items() if key == topic or
                  key.split('#', 1)[0] == topic]
    else:
        chosen = [s for key, s in streams.items()
                  if key.split('#', 1)[0].rsplit('/', 1)[-1] == DEFAULT_TOPIC_SUFFIX]
    if not chosen:
        raise DeviceConfigError(f'bag {bag} has no block stream {topic or "*/measurements"}; '
                                f'block streams are {sorted(streams)}')
    topics = {s.topic for s in chosen}
    if len(topics) > 1:
        raise DeviceConfigError(f'bag {bag} has several measurement streams {sorted(topics)}; '
                                'name one with topic')
    return sorted(chosen, key=lambda s: s.epoch)


class ReplayBackend:
    """
    Back-end ``'replay'``: a recorded block stream re-published with its original timing.

    Parameters
    ----------
    bag : str
        The bag folder.
    topic : str
        The block topic to replay (for example ``'/emfc/measurements'``); empty: the bag's
        only ``*/measurements`` topic.
    pacing : {'receive_time', 'sample_clock', 'fast'}
        How blocks are paced (module docstring).
    speed : float
        Playback speed factor (2: twice as fast), > 0.
    loop : bool
        Start over (in a new epoch) after the last block.
    clock : callable
        Monotonic clock [s].
    sleep : callable
        Sleep function [s].
    """

    name = 'replay'
    host_paced = False
    #: Setpoints are counted and ignored: a recording applies nothing.
    applies_excitation = False
    silence_timeout_s = 0.5
    intrusion_counters: Tuple[str, ...] = ()

    def __init__(self, bag: str = '', *, topic: str = '', pacing: str = 'receive_time',
                 speed: float = 1.0, loop: bool = False,
                 clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        from emfc_ros.core.bag import read_streams      # lazy: rosbags is heavy
        if pacing not in PACINGS:
            raise DeviceConfigError(f'pacing must be one of {PACINGS}, got {pacing!r}')
        if isinstance(speed, bool) or not isinstance(speed, (int, float)) or \
                not 0.0 < float(speed) <= 1e6:
            raise DeviceConfigError(f'speed must be in (0, 1e6], got {speed!r}')
        if not bag:
            raise DeviceConfigError("backend 'replay' needs bag: the folder of a recorded bag")
        try:
            streams = read_streams(bag, on_gap='nan')
        except (OSError, ValueError) as exc:     # BagFormatError, BlockError...
            raise DeviceConfigError(f'cannot read bag {bag}: {exc}') from exc
        self.bag = str(bag)
        self.pacing = pacing
        self.speed = float(speed)
        self.loop = bool(loop)
        self._clock = clock
        self._sleep = sleep
        self._streams = _pick_stream(streams, topic, self.bag)
        first = self._streams[0]
        self.topic = first.topic
        self.sample_rate_Hz = float(first.sample_rate_Hz)
        self.channel_names = tuple(first.channel_names)
        self.channel_units = tuple(first.channel_units)
        for s in self._streams[1:]:
            if s.sample_rate_Hz != self.sample_rate_Hz or \
                    s.samples.shape[0] != len(self.channel_names):
                raise DeviceConfigError(f'{self.topic}: epochs differ in rate or channels')
        self._blocks: List[Block] = []
        self._due_s: List[float] = []
        self._recorded_epoch: List[int] = []
        self._build_schedule()
        sizes = [b.n_samples for b in self._blocks]
        block_size = first.description.block_size if first.description is not None and \
            1 <= first.description.block_size <= MAX_BLOCK_SIZE else max(sizes)
        self.recorded_config = DeviceConfig(
            self.sample_rate_Hz, int(min(max(block_size, 1), MAX_BLOCK_SIZE)),
            tuple(InputChannel(n, u or '1', 1.0) for n, u in
                  zip(self.channel_names, self.channel_units)),
            (OutputChannel('coil_V'), OutputChannel('load_changer_V')))
        #: The recorded description's ``extra.resolution`` (empty when it has none).
        self.recorded_resolution = dict(first.description.extra.get('resolution') or {}) \
            if first.description is not None else {}
        self.config: Optional[DeviceConfig] = None
        self.epoch = 0
        self._running = False
        self._next = 0
        self._t0 = 0.0
        self._lock = threading.Lock()
        self._closed = threading.Event()
        self.counters: Dict[str, int] = dict.fromkeys(
            ('frames_received', 'blocks_delivered', 'gaps', 'missing_samples', 'duplicates',
             'reordered', 'corrupt', 'late', 'heartbeat_misses', 'reconnects', 'foreign',
             'recorded_duplicates', 'setpoint_writes_ignored', 'setpoint_samples_ignored',
             'funcgen_requests_ignored', 'replays_finished'), 0)
        self.counters['recorded_duplicates'] = sum(s.duplicates for s in self._streams)

    def _build_schedule(self) -> None:
        """Split the recorded streams back into their blocks and give each its due time."""
        base_recv = None
        base_time = 0.0
        for stream in self._streams:
            starts = [int(i) for i in stream.block_first_index]
            gap_starts = sorted(g for g, _ in stream.gaps)
            end_all = stream.first_sample_index + stream.n_samples
            first0 = starts[0]
            offset_s = base_time
            for k, start in enumerate(starts):
                end = starts[k + 1] if k + 1 < len(starts) else end_all
                inner = [g for g in gap_starts if start < g <= end]
                if inner:
                    end = inner[0]           # the block ended where the gap began
                lo = start - stream.first_sample_index
                samples = np.ascontiguousarray(
                    stream.samples[:, lo:lo + (end - start)])
                self._blocks.append(Block(start, stream.sample_rate_Hz, stream.epoch,
                                          samples))
                self._recorded_epoch.append(stream.epoch)
                recv = int(stream.block_receive_time_ns[k])
                if base_recv is None:
                    base_recv = recv
                if self.pacing == 'receive_time':
                    due = (recv - base_recv) * 1e-9
                elif self.pacing == 'sample_clock':
                    due = offset_s + (end - first0) / stream.sample_rate_Hz
                else:
                    due = 0.0
                self._due_s.append(due)
            if self._due_s:
                base_time = self._due_s[-1]

    # -- the DeviceBackend interface ---------------------------------------------------------

    @property
    def n_blocks(self) -> int:
        """
        Blocks in the recording.

        Returns
        -------
        int
            The count.
        """
        return len(self._blocks)

    @property
    def finished(self) -> bool:
        """
        Whether every recorded block has been returned (never with ``loop``).

        Returns
        -------
        bool
            True after the last block.
        """
        return self._next >= len(self._blocks)

    def configure(self, config: DeviceConfig) -> None:
        """
        Accept a configuration that matches the recording.

        Parameters
        ----------
        config : DeviceConfig
            Its sample rate and input names must be the recording's (outputs are ignored).

        Raises
        ------
        DeviceConfigError
            If the rate or the channel names differ.
        DeviceError
            If running.
        """
        if self._running:
            raise DeviceError('configure while running: stop first')
        if abs(config.sample_rate_Hz - self.sample_rate_Hz) > 1e-9 * self.sample_rate_Hz:
            raise DeviceConfigError(f'the recording is at {self.sample_rate_Hz} Hz, not '
                                    f'{config.sample_rate_Hz} Hz')
        if tuple(config.input_names) != self.channel_names:
            raise DeviceConfigError(f'the recording has channels {list(self.channel_names)}, '
                                    f'not {list(config.input_names)}')
        self.config = config

    def start(self) -> int:
        """
        Start from the recording's first block in a new epoch.

        Returns
        -------
        int
            The new epoch (1, 2, ...: the replay's own, not the recorded one).
        """
        if self.config is None:
            raise DeviceError('start before configure')
        with self._lock:
            self.epoch += 1
            self._next = 0
            self._t0 = self._clock()
            self._running = True
        return self.epoch

    def stop(self) -> None:
        """Stop returning blocks."""
        self._running = False

    def write_setpoints(self, first_sample_index: int, samples_V: np.ndarray) -> None:
        """
        Count and ignore setpoints (a recording has no actuator).

        Parameters
        ----------
        first_sample_index : int
            Ignored.
        samples_V : numpy.ndarray
            Shape ``(outputs, n)`` [V]; only counted.
        """
        self.counters['setpoint_writes_ignored'] += 1
        self.counters['setpoint_samples_ignored'] += int(np.shape(samples_V)[-1])

    def set_function_generator(self, specs: Sequence[GeneratorSpec]) -> None:
        """
        Count and ignore a function-generator configuration.

        Parameters
        ----------
        specs : sequence of GeneratorSpec
            Ignored.
        """
        self.counters['funcgen_requests_ignored'] += 1

    def read_block(self, timeout_s: float = 1.0) -> Optional[Block]:
        """
        Next recorded block once it is due.

        Parameters
        ----------
        timeout_s : float
            Longest wait [s].

        Returns
        -------
        Block or None
            The block with its recorded first sample index, in the replay's epoch; None when
            not running, finished (after waiting ``timeout_s``) or not due in time.
        """
        timeout_s = max(0.0, float(timeout_s))
        with self._lock:
            if self._running and self._next >= len(self._blocks) and self.loop:
                self.epoch += 1
                self._next = 0
                self._t0 = self._clock()
            if not self._running or self._next >= len(self._blocks) or \
                    self._closed.is_set():
                idle = True
            else:
                idle = False
                i = self._next
                due = self._t0 + self._due_s[i] / self.speed
        if idle:
            self._closed.wait(timeout_s)
            return None
        wait = due - self._clock()
        if wait > timeout_s:
            self._closed.wait(timeout_s)
            return None
        if wait > 0:
            self._sleep(wait)
        with self._lock:
            if not self._running or self._next != i:
                return None
            self._next += 1
            block = self._blocks[i]
            if i > 0 and self._recorded_epoch[i - 1] != self._recorded_epoch[i]:
                self.epoch += 1              # the recording restarted its index: so do we
            n = block.n_samples
            if self.pacing != 'fast' and \
                    self._clock() - due > n / (self.sample_rate_Hz * self.speed):
                self.counters['late'] += 1
            if i > 0 and self._recorded_epoch[i - 1] == self._recorded_epoch[i] and \
                    block.first_sample_index > self._blocks[i - 1].end_index:
                self.counters['gaps'] += 1
                self.counters['missing_samples'] += \
                    block.first_sample_index - self._blocks[i - 1].end_index
            self.counters['frames_received'] += 1
            self.counters['blocks_delivered'] += 1
            if self._next == len(self._blocks):
                self.counters['replays_finished'] += 1
            return Block(block.first_sample_index, block.sample_rate_Hz, self.epoch,
                         block.samples)

    def take_faults(self) -> List[Tuple[str, Optional[int], str, bool]]:
        """
        Faults this back-end found itself: none (the bridge reads its health counters).

        Returns
        -------
        list
            Empty.
        """
        return []

    def health(self) -> Dict[str, int]:
        """
        Replay counters in the shape of the other back-ends' health.

        Returns
        -------
        dict
            Blocks delivered, recorded gaps met, late deliveries, ignored writes.
        """
        with self._lock:
            out = dict(self.counters)
        out['blocks_remaining'] = len(self._blocks) - self._next
        return out

    def description_extra(self) -> Dict[str, Any]:
        """
        What this back-end adds to the measurement description's ``extra``.

        Returns
        -------
        dict
            ``replay_bag`` and ``replay_topic``: what is replayed.
        """
        return {'replay_bag': self.bag, 'replay_topic': self.topic}

    def close(self) -> None:
        """Stop; wake a waiting reader."""
        self._running = False
        self._closed.set()
