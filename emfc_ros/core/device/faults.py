"""
Faults of a device run: events after which the outputs were not what the host commanded.

A fault is latched: once seen it stays until the run is restarted (``~/start``) or the
user acknowledges it (``~/reset``). The daq_bridge reports each on ``/diagnostics`` as
ERROR and in its measurement description (``extra.faults``, a list of
:meth:`Fault.to_dict`); the recorder keeps them in the bag's custom data
(``emfc_ros.faults``); ``emfc-experiment`` fails the run and the identifier refuses the bag.

Kinds (:data:`KINDS`):

``device_watchdog``
    The device's own watchdog tripped (the host was silent for longer than its timeout):
    the outputs were held at their safe values from the device's trip record on, to the end
    of the epoch.
``device_underrun``
    The device ran out of setpoints while streaming (the host wrote them too late): those
    samples were output at the safe values. The device counts them; where they lie is the
    host's estimate (the latest possible position).
``device_setpoint_gap``
    The device filled setpoint samples with the safe values because the setpoint stream had
    a gap (frames lost on the way, or the host skipped ahead after falling behind). Where
    the first gap of the epoch began is the device's record (exact).
``device_setpoint_rejected``
    The device refused setpoint frames of the current epoch (malformed for its
    configuration, or too far ahead): their samples were output at the safe values. The
    first refused frame's index is the device's record (exact).
``device_lost``
    No valid datagram from the device for longer than the device timeout, the device no
    longer knows the host's session (another host took it, or it restarted), or the
    back-end had to reconnect (the stream restarted in a new epoch).
``excitation_watchdog``
    The bridge's excitation watchdog drove the outputs safe while excitation samples were
    still queued, or excitation arrived again after such a trip (the samples between were
    not applied).
``emergency_stop``
    ``~/emergency_stop`` was called.
``safe_outputs_unconfirmed``
    The device did not confirm the request that drives the outputs safe.
``generator_unconfirmed``
    The device did not confirm a change of its function generator made while running (or
    the one restoring it after an emergency stop): it may still output the old one.
``excitation_late``
    Excitation samples arrived after the daq_bridge had written the device samples they were
    due at (the generator, or the link to it, fell more than ``excitation_lead_s`` behind the
    device, or a consumer-paced generator's window is shorter than the lead): the outputs
    were at their safe values there and the late samples were dropped. Where the first of
    them lies is the bridge's own write position (exact).
``excitation_start_missing``
    The daq_bridge mapped an excitation stream onto the device clock from a block after the
    stream's sample 0 (the stream began before the device ran, or the device's clock
    restarted under it): the samples before that block were not applied in this device
    epoch, although a recording may hold them.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple

KINDS = ('device_watchdog', 'device_underrun', 'device_setpoint_gap',
         'device_setpoint_rejected', 'device_lost', 'excitation_watchdog', 'emergency_stop',
         'safe_outputs_unconfirmed', 'generator_unconfirmed', 'excitation_start_missing',
         'excitation_late')
#: Cumulative health counters compared with their values at the start of a run.
BASELINE_KEYS = ('device_underrun_samples', 'device_watchdog_trips', 'reconnects',
                 'device_gap_filled_samples', 'device_setpoint_frames_rejected',
                 'device_losses', 'sessions_lost')


@dataclasses.dataclass(frozen=True)
class Fault:
    """
    One latched fault.

    Attributes
    ----------
    kind : str
        One of :data:`KINDS`.
    device_index : int or None
        First device sample (of the epoch) affected; None when unknown.
    samples : int or None
        Samples affected from ``device_index`` on; None: to the end of the epoch.
    message : str
        What happened, for a person.
    exact : bool
        Whether ``device_index`` is the device's own record (True) or the host's estimate.
    epoch : int
        The device stream epoch the index counts in.
    """

    kind: str
    device_index: Optional[int]
    samples: Optional[int]
    message: str
    exact: bool = False
    epoch: int = 0

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f'fault kind must be one of {KINDS}, got {self.kind!r}')

    def to_dict(self) -> Dict[str, Any]:
        """
        The fault as plain values (JSON and YAML).

        Returns
        -------
        dict
            ``kind``, ``device_index``, ``samples``, ``message``, ``exact``, ``epoch``.
        """
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, doc: Mapping[str, Any]) -> 'Fault':
        """
        Parse :meth:`to_dict`'s output.

        Parameters
        ----------
        doc : mapping
            The values.

        Returns
        -------
        Fault
            The fault.

        Raises
        ------
        ValueError
            If a field is missing or of the wrong type.
        """
        try:
            index = doc.get('device_index')
            samples = doc.get('samples')
            return cls(str(doc['kind']), None if index is None else int(index),
                       None if samples is None else int(samples), str(doc.get('message', '')),
                       bool(doc.get('exact', False)), int(doc.get('epoch', 0) or 0))
        except (KeyError, TypeError, AttributeError) as exc:
            raise ValueError(f'malformed fault record {doc!r}: {exc}') from None

    def experiment_range(self, offset: Optional[int],
                         total: int) -> Optional[Tuple[int, int]]:
        """
        The experiment samples ``[first, end)`` the fault affected.

        Parameters
        ----------
        offset : int or None
            Device index of experiment sample 0 (``excitation_offset_samples``).
        total : int
            Samples in the experiment.

        Returns
        -------
        tuple of int or None
            The range clipped to the experiment; None when the position is unknown (no
            index or no offset). An empty range means the fault fell outside the experiment.
        """
        if self.device_index is None or offset is None:
            return None
        first = self.device_index - int(offset)
        end = total if self.samples is None else first + self.samples
        first, end = max(0, first), min(total, end)
        return (first, max(first, end))


def describe(faults: Sequence[Fault], offset: Optional[int] = None, total: int = 0,
             sample_rate_Hz: float = 0.0) -> str:
    """
    One line per fault, with the experiment samples affected where they are known.

    Parameters
    ----------
    faults : sequence of Fault
        The faults.
    offset : int, optional
        Device index of experiment sample 0.
    total : int
        Samples in the experiment (0: give device indices only).
    sample_rate_Hz : float
        For times in seconds (0: samples only).

    Returns
    -------
    str
        The lines joined with newlines.
    """
    lines = []
    for f in faults:
        where = ''
        span = f.experiment_range(offset, total) if total else None
        if span is not None:
            first, end = span
            if end <= first:
                where = " (outside the experiment's samples)"
            else:
                est = '' if f.exact else 'about '
                where = f'; {est}experiment samples {first} to {end - 1} not applied'
                if sample_rate_Hz > 0:
                    where += f' ({first / sample_rate_Hz:.3f} s to {end / sample_rate_Hz:.3f} s)'
        elif f.device_index is not None:
            where = f' (device sample {f.device_index} of epoch {f.epoch})'
        lines.append(f'{f.kind}: {f.message}{where}')
    return '\n'.join(lines)


def faults_from_extra(extra: Mapping[str, Any]) -> List[Fault]:
    """
    The faults a measurement description's ``extra`` carries.

    Parameters
    ----------
    extra : mapping
        The description's ``extra``.

    Returns
    -------
    list of Fault
        Empty when it carries none.

    Raises
    ------
    ValueError
        If the record is malformed.
    """
    raw = extra.get('faults') or []
    if not isinstance(raw, list):
        raise ValueError(f'extra.faults must be a list, got {type(raw).__name__}')
    return [Fault.from_dict(doc) for doc in raw]


class FaultMonitor:
    """
    Turn a back-end's health into latched faults.

    The cumulative device counters are compared with their values at the start of the run
    (:meth:`reset`), so faults of an earlier run do not count again.
    """

    def __init__(self) -> None:
        self._faults: List[Fault] = []
        self._base: Dict[str, int] = {}
        self._epoch = 0
        self._grown = False

    @property
    def faults(self) -> Tuple[Fault, ...]:
        """The latched faults, oldest first."""
        return tuple(self._faults)

    def has(self, kind: str) -> bool:
        """
        Whether a fault of this kind is latched.

        Parameters
        ----------
        kind : str
            One of :data:`KINDS`.

        Returns
        -------
        bool
            True if latched.
        """
        return any(f.kind == kind for f in self._faults)

    def reset(self, health: Optional[Mapping[str, Any]] = None, epoch: int = 0) -> None:
        """
        Forget the latched faults; take the counters' baseline from ``health``.

        Parameters
        ----------
        health : mapping, optional
            The back-end's health now.
        epoch : int
            The stream epoch of the run.
        """
        self._faults = []
        health = health or {}
        self._base = {k: _int(health.get(k)) for k in BASELINE_KEYS}
        self._epoch = int(epoch or 0)

    def set_epoch(self, epoch: int) -> None:
        """
        The stream epoch the next faults' device indices count in (a device restart).

        Parameters
        ----------
        epoch : int
            The new epoch; latched faults and the counters' baseline stay.
        """
        self._epoch = int(epoch or 0)

    def take_grown(self) -> bool:
        """
        Whether a latched fault grew (more samples) since the last call.

        Returns
        -------
        bool
            True once per growth.
        """
        grown, self._grown = self._grown, False
        return grown

    def add(self, kind: str, device_index: Optional[int], samples: Optional[int],
            message: str, exact: bool = False) -> Fault:
        """
        Latch a fault the host saw itself.

        Parameters
        ----------
        kind : str
            One of :data:`KINDS`.
        device_index : int or None
            First device sample affected.
        samples : int or None
            Samples affected (None: to the end of the epoch).
        message : str
            What happened.
        exact : bool
            Whether the index is exact.

        Returns
        -------
        Fault
            The latched fault.
        """
        fault = Fault(kind, device_index, samples, message, exact, self._epoch)
        self._faults.append(fault)
        return fault

    def add_reported(self, kind: str, device_index: Optional[int], message: str,
                     exact: bool = False) -> Optional[Fault]:
        """
        Latch a fault the back-end found itself (a driver error), to the end of the epoch.

        A fault of the same kind latched already (from the health counters) is widened
        instead: from the exact record of the two (else the earlier estimate) to the end of
        the epoch, with both messages, so that the driver's own code and text are never lost.

        Parameters
        ----------
        kind : str
            One of :data:`KINDS`.
        device_index : int or None
            First device sample affected.
        message : str
            What the back-end said.
        exact : bool
            Whether the index is the device's or the back-end's exact record.

        Returns
        -------
        Fault or None
            The new fault; None when an existing one was widened (or already said it).
        """
        old = next((f for f in self._faults if f.kind == kind), None)
        if old is None:
            return self.add(kind, device_index, None, message, exact)
        if message in old.message:
            return None
        # the exact record where there is one, else the earlier estimate
        if exact and device_index is not None:
            index, is_exact = device_index, True
        elif old.exact or device_index is None:
            index, is_exact = old.device_index, old.exact
        else:
            known = [i for i in (old.device_index, device_index) if i is not None]
            index, is_exact = min(known), False
        widened = Fault(kind, index, None, f'{old.message}; {message}', is_exact, old.epoch)
        self._faults[self._faults.index(old)] = widened
        self._grown = True
        return None

    def observe(self, health: Mapping[str, Any], device_index_now: int,
                received_end: int, device_timeout_s: float) -> List[Fault]:
        """
        Compare the back-end's health with the run's baseline; latch what is new.

        Parameters
        ----------
        health : mapping
            The back-end's health (``device_watchdog_tripped``,
            ``device_watchdog_trip_index``, ``device_underrun_samples``,
            ``device_gap_filled_samples``, ``device_first_gap_index``,
            ``device_setpoint_frames_rejected``, ``device_first_rejected_index``,
            ``device_silent_ms``, ``device_losses``, ``sessions_lost``, ``reconnects``;
            missing keys mean nothing to see).
        device_index_now : int
            The host's estimate of the device's sample index now.
        received_end : int
            End index of the last measurement block received.
        device_timeout_s : float
            Silence after which the device counts as lost [s].

        Returns
        -------
        list of Fault
            The faults latched by this call.
        """
        new: List[Fault] = []
        if _int(health.get('device_watchdog_tripped')) and not self.has('device_watchdog'):
            trip = _int(health.get('device_watchdog_trip_index'), -1)
            exact = trip >= 0
            new.append(self.add(
                'device_watchdog', trip if exact else device_index_now, None,
                "the device's watchdog tripped (the host was silent for longer than its "
                'timeout): outputs held at their safe values to the end of the run', exact))
        under = _int(health.get('device_underrun_samples')) - \
            self._base.get('device_underrun_samples', 0)
        if under > 0:
            old = next((f for f in self._faults if f.kind == 'device_underrun'), None)
            # (a fault to the end of the epoch, samples None, has nothing left to grow)
            if old is None or (old.samples is not None and old.samples < under):
                fault = Fault('device_underrun', max(0, device_index_now - under), under,
                              f'the device ran out of setpoints for {under} samples (the host '
                              'wrote them too late): output at the safe values', False,
                              self._epoch)
                if old is None:
                    self._faults.append(fault)
                    new.append(fault)
                else:
                    self._faults[self._faults.index(old)] = fault
                    self._grown = True
        for kind, key, index_key, what in (
                ('device_setpoint_gap', 'device_gap_filled_samples', 'device_first_gap_index',
                 'setpoint samples filled with the safe values for gaps in the setpoint '
                 'stream (frames lost, or written out of order after the host fell behind)'),
                ('device_setpoint_rejected', 'device_setpoint_frames_rejected',
                 'device_first_rejected_index',
                 'setpoint frames refused (malformed for the configuration): their samples '
                 'were output at the safe values')):
            count = _int(health.get(key)) - self._base.get(key, 0)
            if count > 0 and not self.has(kind):
                first = _int(health.get(index_key), -1)
                exact = first >= 0
                unit = 'samples' if kind == 'device_setpoint_gap' else 'frames'
                new.append(self.add(kind, first if exact else device_index_now, None,
                                    f'the device reports {count} {what} (first at device '
                                    f'sample {first if exact else "unknown"}; {unit} since '
                                    'the start of the run)', exact))
        silent_s = _int(health.get('device_silent_ms')) * 1e-3
        reconnects = _int(health.get('reconnects')) - self._base.get('reconnects', 0)
        losses = _int(health.get('device_losses')) - self._base.get('device_losses', 0)
        disowned = _int(health.get('sessions_lost')) - self._base.get('sessions_lost', 0)
        if (silent_s > device_timeout_s or reconnects > 0 or losses > 0 or disowned > 0) \
                and not self.has('device_lost'):
            if disowned > 0:
                what = ('the device no longer knows the session of this host (another host '
                        'took it after this one fell silent, or it restarted)')
            elif silent_s > device_timeout_s:
                what = (f'no valid datagram from the device for {silent_s:.2f} s (timeout '
                        f'{device_timeout_s:g} s)')
            elif losses > 0:
                what = (f'no valid datagram from the device for longer than its timeout '
                        f'({device_timeout_s:g} s)')
            else:
                what = (f'the device was lost and reconnected ({reconnects} time(s)): its '
                        'stream restarted in a new epoch')
            new.append(self.add('device_lost', received_end, None, what))
        return new


def _int(value: Any, default: int = 0) -> int:
    try:
        return int(value)
    except (TypeError, ValueError, OverflowError):
        return default
