"""
What ``emfc-weigh`` decides, without ROS: actions on a schedule, pacing, the lines it prints.

``emfc-weigh`` (``emfc_ros/cli/weigh.py``) brings up a balance in closed loop and the weighing
node, and acts like a user at the balance: it zeroes, tares and adjusts at the times asked
(each on the first steady reading from that time of the sample clock on, retried on the
next one if the node refuses), and prints every reading. This module holds those decisions:

* :func:`parse_actions` and :class:`ActionQueue`: ``--zero-at``, ``--tare-at``,
  ``--adjust-at T:KG`` as a queue;
* :class:`ExcitationPacer`: when the next block of (zero) excitation may go to a simulator
  that owns time: at ``speed`` simulated seconds per wall second, never more than a window of
  blocks ahead of what it acknowledged;
* :func:`reading_line`, :func:`event_line`: the printed lines;
* :func:`precise_current_window`: the input window (offset, scale) of the precise current on a
  16-bit device input that covers the weighing range with margin.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
import math
from typing import Deque, List, Mapping, Optional, Sequence, Tuple

from emfc_ros.core.weighing.errors import WeighingError

ACTIONS = ('zero', 'tare', 'adjust')


@dataclass(frozen=True)
class Action:
    """
    One calibration action a user asks for.

    Attributes
    ----------
    time_s : float
        From this time of the sample clock on [s] (on the first steady reading).
    kind : str
        ``'zero'``, ``'tare'`` or ``'adjust'``.
    mass_kg : float
        Reference mass of ``'adjust'`` [kg].
    """

    time_s: float
    kind: str
    mass_kg: float = 0.0

    def describe(self) -> str:
        """
        A short text for messages.

        Returns
        -------
        str
            What and from when, ``'adjust with 100 g (from 2 s)'``.
        """
        what = f'adjust with {self.mass_kg * 1e3:g} g' if self.kind == 'adjust' else self.kind
        return f'{what} (from {self.time_s:g} s)'


def _time(text: str, option: str) -> float:
    try:
        t = float(text)
    except ValueError:
        raise WeighingError(f'{option}: {text!r} is not a time [s]') from None
    if not (math.isfinite(t) and t >= 0.0):
        raise WeighingError(f'{option}: {text!r} must be a time >= 0 s')
    return t


def parse_actions(zero_at: Sequence[str], tare_at: Sequence[str],
                  adjust_at: Sequence[str]) -> Tuple[Action, ...]:
    """
    The actions of the command line, in time order (a stable sort: ties keep their kind order).

    Parameters
    ----------
    zero_at, tare_at : sequence of str
        Times [s].
    adjust_at : sequence of str
        ``'time_s:mass_kg'``.

    Returns
    -------
    tuple of Action
        Sorted by time.

    Raises
    ------
    WeighingError
        Naming the option and the malformed value.
    """
    out: List[Action] = [Action(_time(t, '--zero-at'), 'zero') for t in zero_at]
    out += [Action(_time(t, '--tare-at'), 'tare') for t in tare_at]
    for item in adjust_at:
        parts = str(item).split(':')
        if len(parts) != 2:
            raise WeighingError(f'--adjust-at: {item!r} must be time_s:mass_kg (for example '
                                '2.5:0.1)')
        t = _time(parts[0], '--adjust-at')
        try:
            m = float(parts[1])
        except ValueError:
            raise WeighingError(f'--adjust-at: {item!r}: the mass must be a number [kg]') \
                from None
        if not (math.isfinite(m) and 0.0 < m <= 2.0):
            raise WeighingError(f'--adjust-at: {item!r}: the mass must be in (0, 2] kg')
        out.append(Action(t, 'adjust', m))
    return tuple(sorted(out, key=lambda a: a.time_s))


class ActionQueue:
    """
    Calibration actions due on steady readings, one at a time, retried when refused.

    Parameters
    ----------
    actions : sequence of Action
        In time order.
    max_attempts : int
        Refusals of one action before it is given up (reported).
    """

    def __init__(self, actions: Sequence[Action], max_attempts: int = 20) -> None:
        self._pending: Deque[Action] = deque(actions)
        self._in_flight: Optional[Action] = None
        self._attempts = 0
        self.max_attempts = int(max_attempts)
        self.failed: List[Tuple[Action, str]] = []

    @property
    def pending(self) -> Tuple[Action, ...]:
        """Actions not done yet (the one in flight first)."""
        head = (self._in_flight,) if self._in_flight is not None else ()
        return head + tuple(self._pending)

    def due(self, time_s: float, steady: bool) -> Optional[Action]:
        """
        The action to request on a reading, if one is due and none is in flight.

        Parameters
        ----------
        time_s : float
            The reading's sample time [s].
        steady : bool
            Whether the reading is steady.

        Returns
        -------
        Action or None
            The action to request now (then in flight until :meth:`finished`).
        """
        if self._in_flight is not None or not self._pending or not steady:
            return None
        if self._pending[0].time_s > time_s:
            return None
        self._in_flight = self._pending.popleft()
        return self._in_flight

    def finished(self, success: bool, message: str) -> Optional[str]:
        """
        The answer of the action in flight.

        Parameters
        ----------
        success : bool
            Whether the node did it.
        message : str
            Its message.

        Returns
        -------
        str or None
            A reason when the action is given up after ``max_attempts`` refusals.
        """
        action = self._in_flight
        self._in_flight = None
        if action is None or success:
            self._attempts = 0
            return None
        self._attempts += 1
        if self._attempts >= self.max_attempts:
            self._attempts = 0
            self.failed.append((action, message))
            return f'{action.describe()} given up after {self.max_attempts} refusals: {message}'
        self._pending.appendleft(action)      # again, on the next steady reading
        return None


class ExcitationPacer:
    """
    How far (zero) excitation may be sent to a simulator that owns time.

    Parameters
    ----------
    sample_rate_Hz : float
        Sample rate [Hz].
    block_size : int
        Samples per block.
    speed : float
        Simulated seconds per wall second; 0: as fast as the simulator acknowledges.
    window_blocks : int
        Most blocks sent beyond the acknowledged index.
    """

    def __init__(self, sample_rate_Hz: float, block_size: int, speed: float = 1.0,
                 window_blocks: int = 4) -> None:
        if not (math.isfinite(speed) and speed >= 0.0):
            raise WeighingError(f'--speed: {speed!r} must be >= 0 (0: as fast as possible)')
        self.sample_rate_Hz = float(sample_rate_Hz)
        self.block_size = int(block_size)
        self.speed = float(speed)
        self.window_blocks = int(window_blocks)
        self.start_s: Optional[float] = None

    def allowed_index(self, now_s: float, acknowledged_index: int) -> int:
        """
        One past the last sample that may have been sent at wall time ``now_s``.

        Parameters
        ----------
        now_s : float
            Wall (monotonic) time [s]; the first call starts the clock.
        acknowledged_index : int
            Samples the simulator has consumed.

        Returns
        -------
        int
            A whole number of blocks.
        """
        if self.start_s is None:
            self.start_s = now_s
        limit = (int(acknowledged_index) // self.block_size + self.window_blocks) \
            * self.block_size
        if self.speed > 0.0:
            due = (now_s - self.start_s) * self.speed * self.sample_rate_Hz
            limit = min(limit, (int(due // self.block_size) + 1) * self.block_size)
        return limit


def _flag(values: Mapping[str, str]) -> str:
    if values.get('stable') == 'true':
        return 'stable'
    if values.get('calibrated') == 'false':
        return 'uncalibrated'
    return 'unstable'


def reading_line(values: Mapping[str, str], sample_rate_Hz: float,
                 dynamic: Optional[Mapping[str, str]] = None) -> str:
    """
    The printed line of one reading (the values of a ``~/reading`` status).

    ``t 12.300 s   mass +73.48290 g   u 0.190 mg   stable`` (the sample time is the reading's
    last sample), then the dynamic estimate of the same sample when there is one.

    Parameters
    ----------
    values : Mapping
        The reading's values (strings).
    sample_rate_Hz : float
        The stream's rate [Hz] (sample time of the reading).
    dynamic : Mapping, optional
        The dynamic reading of the same sample.

    Returns
    -------
    str
        The line.
    """
    t = (int(values['sample_index']) + 1) / sample_rate_Hz
    mass_g = float(values['mass_kg']) * 1e3
    u_mg = float(values['standard_uncertainty_kg']) * 1e6
    line = f't {t:9.3f} s   mass {mass_g:+11.5f} g   u {u_mg:7.3f} mg   {_flag(values):12s}'
    tare = float(values.get('tare_kg', 0.0) or 0.0)
    if tare:
        line += f'   tare {tare * 1e3:.5f} g'
    if dynamic is not None:
        state = 'settled' if dynamic.get('settled') == 'true' else 'moving'
        line += (f'   dynamic {float(dynamic["mass_kg"]) * 1e3:+11.5f} g '
                 f'(u {float(dynamic["standard_uncertainty_kg"]) * 1e6:.3f} mg, {state})')
    return line


def event_line(time_s: Optional[float], text: str) -> str:
    """
    A printed event (a load change, a calibration, a refusal): ``# 2.000 s: text``.

    Parameters
    ----------
    time_s : float or None
        Sample time [s], if the event has one.
    text : str
        What happened.

    Returns
    -------
    str
        The line.
    """
    return f'# {time_s:9.3f} s: {text}' if time_s is not None else f'# {text}'


def precise_current_window(currents_A: Sequence[float], margin: float = 0.25,
                           bits: int = 16) -> Tuple[float, float]:
    """
    Offset and scale of a device input that carries the precise current over a range.

    Parameters
    ----------
    currents_A : sequence of float
        The coil currents the range needs (e.g. the hold currents of 0 and of the largest
        load) [A].
    margin : float
        Extra span on each side, as a fraction of the range.
    bits : int
        Converter bits (signed codes).

    Returns
    -------
    (float, float)
        ``(offset_A, scale_A_per_code)``: value at code 0 and per code.
    """
    lo, hi = min(currents_A), max(currents_A)
    span = (hi - lo) * (1.0 + 2.0 * margin)
    if span <= 0.0:
        span = max(abs(hi), 1e-3)
    return 0.5 * (lo + hi), span / 2.0 ** bits
