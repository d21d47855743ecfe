"""
The emulated device's core: tasks on one sample clock with NI-DAQmx semantics.

An AI task on the onboard clock is the master: its sample ``k`` is at ``t0 + k / rate`` of
the injected clock. An AO task whose sample clock source is ``/<dev>/ai/SampleClock`` ticks
with it (sample ``k`` of both is the same tick); an AO task on the onboard clock ticks on
its own. At every tick the AO task outputs its next buffered sample; when the host has not
written it and regeneration is off, the generation stops with
``GEN_STOPPED_TO_PREVENT_REGEN_OF_OLD_SAMPLES`` (the output holds its last value, as the
hardware does); with regeneration allowed the samples written repeat cyclically. An AO task
on its own onboard clock with a start trigger ``/<dev>/ai/StartTrigger`` starts at the AI
task's first tick, so at the same rate its sample ``k`` is the AI task's too. AI samples are
quantised to the channel's range (16 bits) and kept in a buffer of the configured size: when
the host reads too late the acquisition stops with ``SAMPLES_NO_LONGER_AVAILABLE``. An AO
task's buffer (regeneration off) holds at most its configured size of samples written and
not yet generated: a write that does not fit is refused with
``SAMPLES_CAN_NOT_YET_BE_WRITTEN`` and writes nothing (the server waits for space up to the
write's timeout first, as the driver does).

The watchdog timer (a watchdog task) expires when it is not fed within its timeout: from the
expiry on, every output is at its expiration state and every running AO task has failed with
``WRITE_FAILED_BECAUSE_WATCHDOG_EXPIRED`` (until the expiration is cleared). A removed device
answers every call with ``DEVICE_REMOVED``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable, Dict, List, Optional, Protocol, Sequence

import numpy as np

from emfc_ros.core.device import daqmx_errors as codes
from emfc_ros.core.device.daqmx_wiring import range_for, resolution_V
from emfc_ros.core.errors import EmfcError


class Plant(Protocol):
    """What the device's terminals are wired to (a balance, or a loopback)."""

    def start(self, sample_rate_Hz: float) -> None:
        """
        The acquisition starts at this sample rate [Hz] (the plant restarts).

        Parameters
        ----------
        sample_rate_Hz : float
            The AI sample clock's rate [Hz].
        """
        ...  # pragma: no cover

    def step(self, ao_V: np.ndarray) -> Dict[str, np.ndarray]:
        """
        AO volts ``(n_ao, n)`` of the device's outputs in order -> AI volts by terminal.

        Parameters
        ----------
        ao_V : numpy.ndarray, shape (n_ao, n)
            What each output drives at the next ``n`` ticks [V], outputs in the device's order.

        Returns
        -------
        dict of str to numpy.ndarray
            The input voltages at those ticks [V], ``n`` each, by AI terminal (``'ai0'``);
            terminals not named read 0 V.
        """
        ...  # pragma: no cover


#: The fastest sample clock the emulated device runs [S/s] (an X Series AI clock).
MAX_RATE_HZ = 2e6


class DaqmxError(EmfcError, RuntimeError):
    """
    An NI-DAQmx error: its code and NI's text.

    Parameters
    ----------
    code : int
        The NI-DAQmx error code (:mod:`emfc_ros.core.device.daqmx_errors`).
    detail : str
        Appended to NI's text on a line of its own (task, channel, property), if not empty.
    """

    def __init__(self, code: int, detail: str = '') -> None:
        self.code = int(code)
        super().__init__(codes.text(code) + (f'\n{detail}' if detail else ''))


@dataclasses.dataclass
class Channel:
    """One virtual channel of a task: a physical channel, its name and range [V]."""

    physical: str
    name: str
    min_V: float
    max_V: float


@dataclasses.dataclass
class Task:
    """One task's configuration and state."""

    name: str
    kind: str = ''                      # 'ai' or 'ao', from the first channel
    channels: List[Channel] = dataclasses.field(default_factory=list)
    rate_Hz: float = 0.0                # 0: on demand
    source: str = ''                    # '' onboard clock, or the AI sample clock
    trigger: str = ''                   # '' none, or the AI start trigger
    buffer_samples: int = 0
    regeneration: bool = True
    running: bool = False
    error: Optional[DaqmxError] = None
    t0: float = 0.0
    produced: int = 0                   # ticks of this task's clock so far
    consumed: int = 0                   # AI: samples read; AO: samples written
    data: List[np.ndarray] = dataclasses.field(default_factory=list)
    written: List[np.ndarray] = dataclasses.field(default_factory=list)   # for regeneration
    last_V: Optional[np.ndarray] = None
    armed: bool = False                 # AO waiting for its start trigger
    underflow_at: int = -1              # AO: the first sample not written in time


@dataclasses.dataclass
class Watchdog:
    """The device's watchdog timer: its timeout [s] and expiration states [V] by terminal."""

    task: str
    timeout_s: float
    expiration_V: Dict[str, float]
    running: bool = False
    fed_at: float = 0.0
    expired: bool = False


class Device:
    """
    One emulated device and its tasks.

    Parameters
    ----------
    plant : Plant
        What the terminals are wired to.
    name : str
        The device name (``'Dev1'``).
    n_ai, n_ao : int
        Analog inputs and outputs.
    clock : callable
        Monotonic time [s] (injected).
    ao_watchdog : bool
        The watchdog timer takes analog-output expiration states (as a CompactDAQ chassis
        with analog-output modules does); False: it covers digital lines only (as an X Series
        device's, which covers its DIO and PFI lines), and AO expiration states are refused.
    """

    def __init__(self, plant: Plant, name: str = 'Dev1', n_ai: int = 8, n_ao: int = 2, *,
                 clock: Callable[[], float], ao_watchdog: bool = True) -> None:
        self.plant = plant
        self.name = name
        self.ao_watchdog = bool(ao_watchdog)
        self.ai_terminals = tuple(f'ai{i}' for i in range(n_ai))
        self.ao_terminals = tuple(f'ao{i}' for i in range(n_ao))
        self.clock = clock
        self.tasks: Dict[str, Task] = {}
        self.ao_V = np.zeros(n_ao)          # what each output drives now
        self.watchdog: Optional[Watchdog] = None
        self.removed = False
        self._now = clock()

    @property
    def sample_clock(self) -> str:
        """The AI sample clock terminal (``'/Dev1/ai/SampleClock'``)."""
        return f'/{self.name}/ai/SampleClock'

    @property
    def start_trigger(self) -> str:
        """The AI start trigger terminal (``'/Dev1/ai/StartTrigger'``)."""
        return f'/{self.name}/ai/StartTrigger'

    def _check_present(self) -> None:
        if self.removed:
            raise DaqmxError(codes.DEVICE_REMOVED, f'Device: {self.name}')

    # -- configuration ------------------------------------------------------------------------

    def create_task(self, name: str) -> Task:
        """
        A new task (its name must be unique).

        Parameters
        ----------
        name : str
            The task's name; DUPLICATE_TASK if the device has one of that name.

        Returns
        -------
        Task
            The task, not configured.
        """
        self._check_present()
        if name in self.tasks:
            raise DaqmxError(codes.DUPLICATE_TASK, f'Task Name: {name}')
        task = Task(name)
        self.tasks[name] = task
        return task

    def task(self, name: str) -> Task:
        """
        The task of a name (INVALID_TASK if none).

        Parameters
        ----------
        name : str
            The task's name.

        Returns
        -------
        Task
            The task.
        """
        try:
            return self.tasks[name]
        except KeyError:
            raise DaqmxError(codes.INVALID_TASK, f'Task Name: {name}') from None

    def clear(self, name: str) -> None:
        """
        Stop and forget a task (unknown names are ignored, as DAQmxClearTask does).

        Parameters
        ----------
        name : str
            The task's name (a watchdog task's too: the watchdog goes with it).
        """
        task = self.tasks.get(name)
        if task is not None and task.running:
            self.stop(task)
        self.tasks.pop(name, None)
        if self.watchdog is not None and self.watchdog.task == name:
            self.watchdog = None

    def add_channels(self, task: Task, kind: str, physical: str, name: str, min_V: float,
                     max_V: float) -> None:
        """
        Add voltage channels (``'Dev1/ai0:2'`` expands) to a task of one kind.

        Parameters
        ----------
        task : Task
            The task; all its channels are of one kind.
        kind : str
            ``'ai'`` or ``'ao'``.
        physical : str
            Physical channels, ``'Dev1/ai0:2, Dev1/ai5'`` (:func:`expand`).
        name : str
            The channels' names, comma separated; ``''`` (or too few) names the rest
            ``'Dev1/ai0'`` and so on.
        min_V, max_V : float
            The channels' range [V], within -10..10 V.
        """
        self._check_present()
        terminals = self.ai_terminals if kind == 'ai' else self.ao_terminals
        names = [n.strip() for n in name.split(',')] if name else []
        phys = expand(physical, self.name)
        limit = 10.0
        if not (-limit <= min_V < max_V <= limit):
            raise DaqmxError(codes.INVALID_ATTRIBUTE_VALUE,
                             f'Property: Max/Min\nRequested Min: {min_V}\n'
                             f'Requested Max: {max_V}\nPossible range: -10 to 10 V')
        for i, p in enumerate(phys):
            if p not in terminals:
                raise DaqmxError(codes.INVALID_PHYS_CHAN_NAME,
                                 f'Physical Channel Name: {p}\nDevice: {self.name}')
            if task.kind and task.kind != kind:
                raise DaqmxError(codes.MULTI_CHAN_TYPES_IN_TASK, f'Task Name: {task.name}')
            task.kind = kind
            label = names[i] if i < len(names) else f'{self.name}/{p}'
            task.channels.append(Channel(p, label, float(min_V), float(max_V)))
        if kind == 'ao':
            task.last_V = np.zeros(len(task.channels))

    def timing(self, task: Task, source: str, rate_Hz: float, buffer_samples: int) -> None:
        """
        Sample-clock timing, continuous (``source`` '' or the AI sample clock).

        Parameters
        ----------
        task : Task
            The task.
        source : str
            ``''`` or ``'OnboardClock'`` for the task's own clock, or :attr:`sample_clock` (AO
            tasks only) to tick with the AI task.
        rate_Hz : float
            Sample rate [Hz], up to MAX_RATE_HZ.
        buffer_samples : int
            Buffer size [samples per channel], at least 1.
        """
        self._check_present()
        if source in ('OnboardClock',):
            source = ''
        if source not in ('', self.sample_clock) or (source and task.kind != 'ao'):
            raise DaqmxError(codes.INVALID_ROUTING_SOURCE_TERMINAL_NAME,
                             f'Source Device: {self.name}\nSource Terminal: {source}')
        if not 0.0 < rate_Hz <= MAX_RATE_HZ:
            raise DaqmxError(codes.INVALID_ATTRIBUTE_VALUE,
                             f'Property: SampClk.Rate\nRequested Value: {rate_Hz}\n'
                             f'Possible Values: 0 to {MAX_RATE_HZ:g}')
        task.rate_Hz = float(rate_Hz)
        task.source = source
        task.buffer_samples = max(int(buffer_samples), 1)

    def start_trigger_on(self, task: Task, source: str) -> None:
        """
        A digital-edge start trigger: only the AI start trigger is routed.

        Parameters
        ----------
        task : Task
            An AO task.
        source : str
            :attr:`start_trigger`.
        """
        self._check_present()
        if source != self.start_trigger or task.kind != 'ao':
            raise DaqmxError(codes.INVALID_ROUTING_SOURCE_TERMINAL_NAME,
                             f'Source Device: {self.name}\nSource Terminal: {source}')
        task.trigger = source

    def create_watchdog(self, task_name: str, timeout_s: float,
                        expiration_V: Dict[str, float]) -> Watchdog:
        """
        A watchdog task: outputs ``{'ao0': V}`` on expiry; ``timeout_s`` > 0.

        Parameters
        ----------
        task_name : str
            The watchdog task's name (unique).
        timeout_s : float
            Time without a feed after which it expires [s], > 0.
        expiration_V : dict of str to float
            Output states on expiry [V] by AO terminal (``'ao0'``); more can be added later.

        Returns
        -------
        Watchdog
            The device's watchdog, not started.
        """
        self._check_present()
        for term in expiration_V:
            if term not in self.ao_terminals:
                raise DaqmxError(codes.INVALID_PHYS_CHAN_NAME,
                                 f'Physical Channel Name: {term}\nDevice: {self.name}')
        if not timeout_s > 0.0:
            raise DaqmxError(codes.INVALID_ATTRIBUTE_VALUE,
                             f'Property: Watchdog.Timeout\nRequested Value: {timeout_s}')
        if task_name in self.tasks:
            raise DaqmxError(codes.DUPLICATE_TASK, f'Task Name: {task_name}')
        self.tasks[task_name] = Task(task_name, kind='watchdog')
        self.watchdog = Watchdog(task_name, float(timeout_s), dict(expiration_V))
        return self.watchdog

    def feed_watchdog(self) -> None:
        """Reset the watchdog timer (DAQmxControlWatchdogTask reset)."""
        self._check_present()
        self.advance()
        if self.watchdog is not None:
            self.watchdog.fed_at = self._now

    def clear_expiration(self) -> None:
        """Clear an expired watchdog (the outputs return to their tasks)."""
        self.advance()
        if self.watchdog is not None:
            self.watchdog.expired = False
            self.watchdog.fed_at = self._now

    def remove(self) -> None:
        """The device is gone (unplugged): every later call fails with DEVICE_REMOVED."""
        self.removed = True

    # -- running ------------------------------------------------------------------------------

    def _master(self) -> Optional[Task]:
        return next((t for t in self.tasks.values() if t.kind == 'ai' and t.running), None)

    def start(self, task: Task) -> None:
        """
        Start a task: an onboard-clocked one from now, a slaved one at its master's tick.

        Parameters
        ----------
        task : Task
            The task; an AO task on the AI sample clock or start trigger waits (armed) until the
            AI task starts.
        """
        self._check_present()
        self.advance()
        task.error = None
        now = self._now
        if task.kind == 'watchdog':
            self.watchdog.running = True
            self.watchdog.fed_at = now
        elif task.kind == 'ai':
            if self._master() is not None:
                raise DaqmxError(codes.RESOURCE_ALREADY_RESERVED,
                                 f'Task Name: {task.name}\nDevice: {self.name}')
            task.produced = task.consumed = 0
            task.data = []
            self.plant.start(task.rate_Hz)
            now = self._now = max(self._now, self.clock())     # the plant may take a while
            for other in self.tasks.values():
                if other.kind == 'ao' and other.armed:
                    other.armed = False
                    other.running = True
                    other.t0 = now
        elif task.kind == 'ao':
            task.produced = 0
            if not task.rate_Hz:
                task.running = True
                return
            if task.source or task.trigger:
                master = self._master()
                if task.source and master is None:
                    # a slaved task waits for the AI clock; NI starts the slave first
                    task.armed = True
                    return
                if task.trigger and master is None:
                    task.armed = True
                    return
                if master is not None and task.source:
                    task.produced = master.produced     # joins at the master's next tick
        task.running = True
        task.t0 = now

    def stop(self, task: Task) -> None:
        """
        Stop a task (AO outputs hold their last value).

        Parameters
        ----------
        task : Task
            The task.
        """
        self.advance()
        task.running = False
        task.armed = False
        if task.kind == 'watchdog' and self.watchdog is not None:
            self.watchdog.running = False

    def advance(self) -> None:
        """Run every clock up to now (the watchdog's expiry first, where it lies before)."""
        if self.removed:
            return
        now = self.clock()
        dog = self.watchdog
        if dog is not None and dog.running and not dog.expired and \
                now - dog.fed_at > dog.timeout_s:
            self._advance_to(dog.fed_at + dog.timeout_s)
            self._expire()
        self._advance_to(now)

    def _expire(self) -> None:
        dog = self.watchdog
        dog.expired = True
        for term, volts in dog.expiration_V.items():
            self.ao_V[self.ao_terminals.index(term)] = volts
        for task in self.tasks.values():
            if task.kind == 'ao' and task.running and task.error is None:
                task.error = DaqmxError(codes.WRITE_FAILED_BECAUSE_WATCHDOG_EXPIRED,
                                        f'Task Name: {task.name}')

    def _advance_to(self, now: float) -> None:
        self._now = max(self._now, now)
        now = self._now
        master = self._master()
        if master is not None:
            due = int(math.floor((now - master.t0) * master.rate_Hz + 1e-9)) - master.produced
            if due > 0:
                self._ticks(master, due)
        slaves = self._slaves()
        for task in self.tasks.values():
            if task.kind == 'ao' and task.running and task.rate_Hz and task not in slaves:
                due = int(math.floor((now - task.t0) * task.rate_Hz + 1e-9)) - task.produced
                if due > 0:
                    self._generate(task, due)
                    self._apply(task)

    def _slaves(self) -> List[Task]:
        # AO tasks ticking with the AI clock: on its sample clock, or started by its start
        # trigger at the same rate (their clocks derive from one timebase: same ticks)
        master = self._master()
        return [t for t in self.tasks.values() if t.kind == 'ao' and t.running and
                (t.source or (t.trigger and master is not None
                              and t.rate_Hz == master.rate_Hz))]

    def _generate(self, task: Task, n: int) -> np.ndarray:
        """The next ``n`` samples of an AO task (underflow stops it, holding the last value)."""
        out = np.repeat(task.last_V[:, None], n, axis=1)
        if task.error is not None:
            task.produced += n
            return out
        if task.regeneration and task.written:
            ring = np.concatenate(task.written, axis=1)
            idx = (task.produced + np.arange(n)) % ring.shape[1]
            out = ring[:, idx]
        else:
            have = task.consumed - task.produced
            take = min(n, max(0, have))
            if take:
                out[:, :take] = self._pop(task, take)
            if take < n:
                task.error = DaqmxError(codes.GEN_STOPPED_TO_PREVENT_REGEN_OF_OLD_SAMPLES,
                                        f'Task Name: {task.name}\n'
                                        f'Sample: {task.produced + take}')
                task.underflow_at = task.produced + take
                if take:
                    out[:, take:] = out[:, take - 1:take]
        task.produced += n
        task.last_V = out[:, -1].copy()
        return out

    def _pop(self, task: Task, n: int) -> np.ndarray:
        parts, need = [], n
        while need:
            head = task.data[0]
            if head.shape[1] <= need:
                parts.append(task.data.pop(0))
                need -= head.shape[1]
            else:
                parts.append(head[:, :need])
                task.data[0] = head[:, need:]
                need = 0
        return np.concatenate(parts, axis=1)

    def _expired_terminals(self) -> Dict[int, float]:
        dog = self.watchdog
        if dog is None or not dog.expired:
            return {}
        return {self.ao_terminals.index(t): v for t, v in dog.expiration_V.items()}

    def _apply(self, task: Task) -> None:
        held = self._expired_terminals()
        for ch, v in zip(task.channels, task.last_V):
            i = self.ao_terminals.index(ch.physical)
            self.ao_V[i] = held.get(i, v)

    def _ticks(self, master: Task, n: int) -> None:
        ao = np.repeat(self.ao_V[:, None], n, axis=1)
        held = self._expired_terminals()
        for task in self._slaves():
            values = self._generate(task, n)
            for row, ch in zip(values, task.channels):
                i = self.ao_terminals.index(ch.physical)
                ao[i] = held.get(i, row)
            self._apply(task)
        volts = self.plant.step(ao)
        rows = []
        for ch in master.channels:
            full = range_for(max(abs(ch.min_V), abs(ch.max_V)))
            step = resolution_V(full)
            v = np.asarray(volts.get(ch.physical, np.zeros(n)), dtype=np.float64)
            rows.append(np.clip(np.round(v / step) * step, -full, full - step))
        master.data.append(np.vstack(rows))
        master.produced += n
        if master.error is None and master.produced - master.consumed > master.buffer_samples:
            master.error = DaqmxError(codes.SAMPLES_NO_LONGER_AVAILABLE,
                                      f'Task Name: {master.name}\n'
                                      f'Sample: {master.consumed}')
        if len(master.data) > 64:               # keep the buffer's pieces few
            master.data = [np.concatenate(master.data, axis=1)]

    def available(self, task: Task) -> int:
        """
        AI samples acquired and not yet read.

        Parameters
        ----------
        task : Task
            An AI task.

        Returns
        -------
        int
            Samples per channel.
        """
        self._check_present()
        self.advance()
        return task.produced - task.consumed

    def read(self, task: Task, n: int) -> np.ndarray:
        """
        Read ``n`` samples per channel of a running AI task (now; the caller waits).

        Parameters
        ----------
        task : Task
            A running AI task.
        n : int
            Samples per channel.

        Returns
        -------
        numpy.ndarray, shape (channels, n)
            The next samples [V], quantised to the channels' ranges.

        Raises
        ------
        DaqmxError
            The task's latched error, or SAMPLES_NOT_YET_AVAILABLE when fewer are there.
        """
        self._check_present()
        self.advance()
        if task.error is not None:
            raise task.error
        if not task.running:
            raise DaqmxError(codes.INVALID_TASK, f'Task Name: {task.name} (not running)')
        if task.produced - task.consumed < n:
            raise DaqmxError(codes.SAMPLES_NOT_YET_AVAILABLE,
                             f'Task Name: {task.name}\nSamples Requested: {n}')
        task.consumed += n
        return self._pop(task, n)

    def space_available(self, task: Task) -> int:
        """
        Samples per channel an AO task's buffer takes now (NI's ``space_avail``).

        Parameters
        ----------
        task : Task
            An AO task.

        Returns
        -------
        int
            Its buffer size less the samples written and not yet generated; unbounded (a
            large number) on demand or with regeneration (the buffer is then what was
            written).
        """
        self.advance()
        return self._space(task)

    @staticmethod
    def _space(task: Task) -> int:
        """:meth:`space_available` at the device's present (no advance)."""
        if not task.rate_Hz or task.regeneration:
            return 1 << 62
        return max(task.buffer_samples - (task.consumed - task.produced), 0)

    def write(self, task: Task, samples_V: np.ndarray) -> int:
        """
        Append samples ``(channels, n)`` [V] to an AO task's buffer; returns n written.

        Parameters
        ----------
        task : Task
            An AO task (without a sample rate: on demand, the last sample is output at once).
        samples_V : numpy.ndarray
            Reshaped to ``(channels, n)`` [V]; clipped to the channels' ranges.

        Returns
        -------
        int
            ``n``, the samples per channel written.

        Raises
        ------
        DaqmxError
            The task's latched error (an underflow, an expired watchdog), or
            ``SAMPLES_CAN_NOT_YET_BE_WRITTEN`` when the samples do not fit in the buffer
            (nothing written).
        """
        self._check_present()
        self.advance()
        if task.error is not None:
            raise task.error
        if self.watchdog is not None and self.watchdog.expired:
            raise DaqmxError(codes.WRITE_FAILED_BECAUSE_WATCHDOG_EXPIRED,
                             f'Task Name: {task.name}')
        data = np.asarray(samples_V, dtype=np.float64).reshape(len(task.channels), -1)
        space = self._space(task)
        if data.shape[1] > space:
            raise DaqmxError(codes.SAMPLES_CAN_NOT_YET_BE_WRITTEN,
                             f'Task Name: {task.name}\nSamples to write: {data.shape[1]}\n'
                             f'Space available in buffer: {space}')
        lo = np.array([c.min_V for c in task.channels])[:, None]
        hi = np.array([c.max_V for c in task.channels])[:, None]
        data = np.clip(data, lo, hi)
        if not task.rate_Hz:                # on demand: applied at once
            task.last_V = data[:, -1].copy()
            self._apply(task)
            return data.shape[1]
        if task.regeneration:
            task.written.append(data)
        else:
            task.data.append(data)
        task.consumed += data.shape[1]
        return data.shape[1]


def expand(physical: str, device: str) -> Sequence[str]:
    """
    ``'Dev1/ai0:2, Dev1/ai5'`` to ``['ai0', 'ai1', 'ai2', 'ai5']``.

    Parameters
    ----------
    physical : str
        Physical channels, comma separated; a range ``a:b`` may run down.
    device : str
        The device's name; a channel of another device is INVALID_PHYS_CHAN_NAME.

    Returns
    -------
    list of str
        The terminals in order.
    """
    out: List[str] = []
    for part in (p.strip() for p in physical.split(',') if p.strip()):
        dev, _, term = part.rpartition('/')
        if dev.lstrip('/') != device:
            raise DaqmxError(codes.INVALID_PHYS_CHAN_NAME, f'Physical Channel Name: {part}')
        prefix = term.rstrip('0123456789:')
        span = term[len(prefix):]
        if ':' in span:
            a, b = (int(x) for x in span.split(':'))
            step = 1 if b >= a else -1
            out.extend(f'{prefix}{i}' for i in range(a, b + step, step))
        else:
            out.append(term)
    return out
