"""
The simulated balance behind the plant_simulator node, without ROS: a :class:`PlantSession`.

The session decides everything the node used to: the time modes (``owner``: each excitation
block is simulated when it arrives; ``wall``: paced by the injected wall clock, 0 V and an
underrun when nothing is queued; ``lockstep``: one controller period per effort command), the
excitation queue and its acknowledgements (repeated while no excitation follows), the load
schedule and run-time load changes (applied at their sample and announced), the effort
command and its watchdog (:mod:`emfc_ros.core.device_contract`), the joint states on the
device's sample grid, saturation and underrun counters and the diagnostic values. Every call
takes the time it happens at (``now_s``, monotonic seconds) and returns what to publish, in
order, as :mod:`emfc_ros.core.sim.plant_events`.

Thread model: every public method takes the session's own lock (re-entrant), so the node may
call it from any executor thread (timers, subscriptions, services and parameter callbacks);
the returned events are plain data the caller publishes after the call.
"""

from __future__ import annotations

import math
import threading
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from emfc_ros.core.blocks import Block
from emfc_ros.core.device_contract import (
    array_command_effort, CommandError, EffortCommand, joint_command_effort, measurement_groups,
    state_sample_offsets)
from emfc_ros.core.errors import BlockError
from emfc_ros.core.excitation_queue import DROPPED, ExcitationQueue
from emfc_ros.core.model.actuation import coil_setpoint_for_force_V
from emfc_ros.core.sim.channels import channel_names, channel_units
from emfc_ros.core.sim.load_schedule import LoadSchedule
from emfc_ros.core.sim.lockstep import Lockstep
from emfc_ros.core.sim.monitor import saturation_counts
from emfc_ros.core.sim.plant_config import PlantConfig, runtime_refusal
from emfc_ros.core.sim.plant_events import (
    Acknowledgement, ClockTick, DescriptionChanged, JointStates, LogLine, MeasurementBlock)
from emfc_ros.core.sim.plant_outputs import locked as _locked, PlantOutputs
from emfc_ros.core.sim.state_rate import StateRateLimiter

#: An acknowledgement is published again after this long without new excitation [s]: the
#: last one of a window may be lost like any small message, and the generator would wait
#: ack_timeout_s before sending again.
ACK_REPEAT_S = 0.05
#: Repetitions of one acknowledgement at most (then the generator's re-send takes over).
ACK_REPEATS = 20
#: Run-time load changes kept in the measurement description (the latest).
MAX_LOAD_CHANGES = 100
#: Blocks one wall-mode tick simulates at most (it catches up over the next ticks).
WALL_BUDGET_BLOCKS = 64
#: Shortest spacing of repeated warnings of one kind [s] (excitation, commands).
THROTTLE_S = {'excitation': 5.0, 'command': 2.0}


class PlantSession(PlantOutputs):
    """
    The simulated balance between excitation and commands in and measurements out.

    Parameters
    ----------
    config : PlantConfig
        The checked configuration; its last error (if any) is the session's ``error``.
    sim : Simulator or ClosedLoopSimulator or None
        The simulator (None: refused, the session reports ``error`` and simulates nothing).
    start_s : float
        Monotonic time of the start [s] (wall mode: sample 0).
    error : str
        A further reason the session refuses to simulate ('' for none).
    """

    def __init__(self, config: PlantConfig, sim, start_s: float, error: str = '') -> None:
        self._mutex = threading.RLock()
        self.config = config
        self.rate = float(config.sample_rate_Hz)
        self.mode = config.time_mode
        self.sim = sim
        self.error = error or (config.errors[-1] if config.errors else '')
        self.clock_conflict = ''
        self.channel_names = tuple(sim.channel_names) if sim is not None else \
            channel_names(reference=True)
        self.channel_units = tuple(sim.channel_units) if sim is not None else \
            channel_units(reference=True)
        self._row = {name: i for i, name in enumerate(self.channel_names)}
        #: Group name to its rows of ``channel_names`` (empty without ``publish_groups``).
        self.groups = measurement_groups(self.channel_names, self.channel_units) \
            if config.publish_groups else {}
        self.queue = ExcitationQueue([0.0, 0.0])
        self.lock = Lockstep(period=config.lockstep_period, delay=config.command_delay_periods,
                             match=config.lockstep_match)
        self.command = EffortCommand()
        self.states = StateRateLimiter(config.max_state_wall_rate_Hz)
        self.schedule = LoadSchedule(config.load_schedule)
        self.load_kg = float(config.load_mass_kg)
        self.coupled = bool(config.load_changer_coupled)
        self.load_changes: List[List] = []      # [stream sample index, load [kg]] as applied
        self.start_s = float(start_s)
        #: Wall mode: the stamp of sample 0 [ns] (the node's clock at the first step).
        self._wall_stamp0_ns: Optional[int] = None
        self.epoch = 0
        self.next_index = 0         # stream index the next simulated sample carries
        self.sim_samples = 0
        self.blocks_in = self.blocks_out = self.clocks_out = 0
        self.malformed = self.bad_commands = self.acks_repeated = 0
        self.last_error = ''
        self.saturation: Dict[str, int] = {}
        self.last_position_m = 0.0
        self._ack: Optional[Tuple[int, float, int]] = None   # index, time [s], repetitions
        self._warned: Dict[str, float] = {}

    @property
    def simulating(self) -> bool:
        """Whether excitation is taken (a simulator and no second clock)."""
        return self.sim is not None and not self.clock_conflict

    # -- inputs --------------------------------------------------------------------------

    @_locked
    def on_excitation(self, block: Block, now_s: float) -> list:
        """
        An excitation block [V] (coil, load changer) arrived.

        Parameters
        ----------
        block : Block
            The block, two channels.
        now_s : float
            Monotonic time [s].

        Returns
        -------
        list
            Events to publish.
        """
        if not self.simulating:
            return self.refuse_excitation('', now_s)
        try:
            if abs(block.sample_rate_Hz - self.rate) > 1e-9 * self.rate:
                raise BlockError(f'excitation at {block.sample_rate_Hz} Hz, simulator runs at '
                                 f'{self.rate} Hz')
            kind = self.queue.push(block)
        except BlockError as exc:
            return self.refuse_excitation(str(exc), now_s)
        self.blocks_in += 1
        out: list = []
        if kind in DROPPED and block.epoch == self.queue.epoch and self.queue.head_index:
            # A block we already have (counted): its sender did not hear our acknowledgement,
            # so say again how far we are, or a consumer-paced generator waits for nothing.
            self._acknowledge(self.queue.head_index, now_s, out)
            return out
        if self.epoch != block.epoch and self.mode == 'owner':
            self.epoch = block.epoch
            out.append(DescriptionChanged())
        if self.mode == 'owner' and self.queue.queued:
            first = self.queue.head_index
            setpoints, _ = self.queue.pop(self.queue.queued)
            self._simulate(first, setpoints, self._sim_time_ns(), now_s, out)
            self._acknowledge(self.queue.head_index, now_s, out)
        return out      # wall and lockstep: queued, consumed on their own clock

    @_locked
    def refuse_excitation(self, reason: str, now_s: float) -> list:
        """
        An excitation message that is no block (``reason``), or one the session cannot take.

        Parameters
        ----------
        reason : str
            Why it is refused.
        now_s : float
            Monotonic time [s].

        Returns
        -------
        list
            A warning (at most one per :data:`THROTTLE_S` of its kind).
        """
        self.malformed += 1
        if not self.simulating:
            self.last_error = self.error
            return []
        self.last_error = reason
        return self._warn('excitation', f'excitation block dropped: {reason}', now_s)

    @_locked
    def on_joint_command(self, names: Sequence[str], efforts: Sequence[float],
                         stamp_ns: int, now_s: float) -> list:
        """
        A ``joint_commands`` message: joint names, efforts [N], header stamp [ns].

        Parameters
        ----------
        names, efforts : sequence
            The message's joints and efforts [N].
        stamp_ns : int
            Its header stamp [ns].
        now_s : float
            Monotonic time [s].

        Returns
        -------
        list
            Events to publish.
        """
        try:
            effort = joint_command_effort(names, efforts)
        except CommandError as exc:
            return self._bad_command(str(exc), now_s)
        return self.on_command(effort, stamp_ns, 'joint_commands', now_s)

    @_locked
    def on_array_command(self, data: Sequence[float], now_s: float) -> list:
        """
        A ``commands`` message: one effort [N], no stamp.

        Parameters
        ----------
        data : sequence of float
            The message's data.
        now_s : float
            Monotonic time [s].

        Returns
        -------
        list
            Events to publish.
        """
        try:
            effort = array_command_effort(data)
        except CommandError as exc:
            return self._bad_command(str(exc), now_s)
        return self.on_command(effort, None, 'commands', now_s)

    @_locked
    def on_command(self, effort_N: float, stamp_ns: Optional[int], topic: str,
                   now_s: float) -> list:
        """
        An effort command, the coil force [N].

        Owner and wall modes: held (added to the excitation from the next block on) until
        the watchdog returns it to 0 N. Lockstep mode: the total coil force answering the
        waiting state (matched by ``stamp_ns``; None matches any), which steps one period.

        Parameters
        ----------
        effort_N : float
            The force [N].
        stamp_ns : int or None
            Its header stamp [ns] (None: a topic without stamps).
        topic : str
            Where it came from (for the messages).
        now_s : float
            Monotonic time [s].

        Returns
        -------
        list
            Events to publish.
        """
        if not math.isfinite(effort_N):
            prefix = f'{topic}: ' if self.mode == 'lockstep' else ''
            return self._bad_command(f'{prefix}effort command {effort_N!r} N is not finite',
                                     now_s)
        if self.mode != 'lockstep':
            self.command.set(effort_N, now_s)
            return []
        if not self.lock.answers(stamp_ns):
            return []
        volts = coil_setpoint_for_force_V(self.sim.params, effort_N, self.last_position_m)
        self.lock.command(volts)
        self.command.set(effort_N, now_s)
        out: list = []
        self._lockstep_step(self.lock.period, now_s, out)
        return out

    @_locked
    def tick(self, now_s: float, stamp_ns: int = 0, state_subscribed: bool = False) -> list:
        """
        The timer: repeat an acknowledgement, step the wall clock, start or re-publish lockstep.

        Parameters
        ----------
        now_s : float
            Monotonic time [s].
        stamp_ns : int
            Wall mode: the node's clock now [ns]; at the first step it fixes the stamp of
            sample 0, every state after is stamped from there on the sample clock.
        state_subscribed : bool
            Lockstep mode: ``joint_states`` has a subscriber (the first state waits for it).

        Returns
        -------
        list
            Events to publish.
        """
        out: list = []
        if self._ack is not None:
            index, at, repeats = self._ack
            if repeats < ACK_REPEATS and now_s - at >= ACK_REPEAT_S:
                out.append(Acknowledgement(index))
                self._ack = (index, now_s, repeats + 1)
                self.acks_repeated += 1
        if self.mode == 'wall' and self.sim is not None:
            block = self.config.block_size
            due = int((now_s - self.start_s) * self.rate) // block * block
            for _ in range(WALL_BUDGET_BLOCKS):
                if self.next_index + block > due:
                    break
                had = self.queue.queued
                setpoints, _ = self.queue.pop(block)
                # stamped on the sample clock from sample 0 (the device contract: the
                # daq_bridge's rule), not from when the timer happened to run
                if self._wall_stamp0_ns is None:
                    self._wall_stamp0_ns = stamp_ns - int(round(self.next_index * 1e9
                                                                / self.rate))
                base = self._wall_stamp0_ns + int(round(self.next_index * 1e9 / self.rate))
                self._simulate(self.next_index, setpoints, base, now_s, out)
                if had:
                    self._acknowledge(self.queue.head_index, now_s, out)
        elif self.mode == 'lockstep' and self.sim is not None and self.lock.period and \
                not self.error:
            if not self.lock.started:
                if state_subscribed:
                    self.lock.start(float(self.sim.hold_setpoints_V[0]), now_s)
                    self._lockstep_step(1, now_s, out)      # sample 0: the state at t_0
            elif self.lock.republish_due(now_s, self.config.command_timeout_s):
                out += [self.lock.state, ClockTick(self.lock.stamp_ns)]
                self.clocks_out += 1
        return out

    # -- run-time changes ----------------------------------------------------------------

    @_locked
    def set_load(self, mass_kg: float, coupled: bool) -> list:
        """
        Put a load on the pan from the next simulated sample; announce it.

        Parameters
        ----------
        mass_kg : float
            Mass on the pan [kg].
        coupled : bool
            The load changer's moving mass coupled to the pan.

        Returns
        -------
        list
            Events to publish (the new description), none without a simulator.
        """
        if self.sim is None:
            return []
        return self._apply_load(mass_kg, coupled, self.next_index)

    @_locked
    def set_parameters(self, values: Mapping[str, Any]) -> Tuple[str, list]:
        """
        Run-time parameter changes: checked all, then applied (a new load from the next sample).

        Parameters
        ----------
        values : mapping
            Parameter name to its new value (the node's names).

        Returns
        -------
        tuple
            The reason they are refused ('' when accepted) and the events to publish.
        """
        for name, value in values.items():
            reason = runtime_refusal(name, value, self.rate, self.mode)
            if reason:
                return reason, []
        cfg = self.config
        cfg.state_rate_Hz = float(values.get('state_rate_Hz', cfg.state_rate_Hz))
        cfg.command_timeout_s = float(values.get('command_timeout_s', cfg.command_timeout_s))
        load = float(values.get('load_mass_kg', self.load_kg))
        coupled = bool(values.get('load_changer_coupled', self.coupled))
        if (load, coupled) == (self.load_kg, self.coupled):
            return '', []       # as it is (the node's parameter following a scheduled load)
        return '', self.set_load(load, coupled)

    @_locked
    def replace_simulator(self, sim) -> list:
        """
        New balance parameters: simulate on with ``sim`` from its operating point.

        Parameters
        ----------
        sim : Simulator or ClosedLoopSimulator
            The new simulator (same sample rate and channels).

        Returns
        -------
        list
            Events to publish.
        """
        self.sim = sim
        if self.mode != 'lockstep' or self.lock.period:
            self.error = self.clock_conflict     # a second clock stays refused
        if self.lock.started:
            self.lock.hold_V = float(sim.hold_setpoints_V[0])
        return [LogLine('info', 'new balance parameters: simulator restarted at its '
                                'operating point'), DescriptionChanged()]

    @_locked
    def fail(self, reason: str, clock_conflict: bool = False) -> None:
        """
        Stop simulating for ``reason`` (a second clock with ``clock_conflict``).

        Parameters
        ----------
        reason : str
            Why.
        clock_conflict : bool
            The reason is another publisher of the plant's clock: no balance change clears it.
        """
        self.error = reason
        if clock_conflict:
            self.clock_conflict = reason

    @_locked
    def reset(self) -> Tuple[bool, str]:
        """
        Back to the operating point; simulated time and sample indices go on.

        Returns
        -------
        tuple
            Success and the message of the ``~/reset`` service.
        """
        if self.sim is None:
            return False, self.error
        self.sim.reset()
        if self.mode == 'lockstep':
            self.lock.back_to_hold()
        return True, 'simulator state reset to the operating point'

    # -- simulation ----------------------------------------------------------------------

    def _simulate(self, first: int, setpoints: np.ndarray, stamp_ns: int, now_s: float,
                  out: list) -> None:
        """Owner and wall modes: add the effort command, simulate, clock, block, states."""
        effort = self.command.value(now_s, self.config.command_timeout_s)
        if effort != 0.0:
            setpoints = setpoints.copy()
            setpoints[0] += coil_setpoint_for_force_V(self.sim.params, effort,
                                                      float(self.last_position_m))
        block = self._step(first, setpoints, out)
        self.sim_samples += setpoints.shape[1]
        if self.mode == 'owner':
            # Tick, then /clock (the end of the block: when its last sample exists), then
            # the outputs, so that a use_sim_time subscriber stamps them with simulated time.
            out.append(ClockTick(self._sim_time_ns()))
            self.clocks_out += 1
        out.append(MeasurementBlock(first, block))
        self.blocks_out += 1
        offsets = state_sample_offsets(first, block.shape[1], self.rate,
                                       float(self.config.state_rate_Hz))
        if self.mode == 'owner':
            offsets = offsets[self.states.choose(len(offsets), now_s)]
        if len(offsets):
            out.append(self._states_at(block, offsets, stamp_ns))
            self.states.published += len(offsets)

    def _states_at(self, block: np.ndarray, offsets: np.ndarray, stamp_ns: int) -> JointStates:
        """The joint states at ``offsets`` of a block whose sample 0 is at ``stamp_ns``."""
        truth = block[self._row.get('position_true_m', self._row['position_m'])]
        n = block.shape[1]
        velocity = np.gradient(truth) * self.rate if n > 1 else np.zeros(n)
        stamps = stamp_ns + np.round(offsets * 1e9 / self.rate).astype(np.int64)
        return JointStates(stamps, block[self._row['position_m'], offsets], velocity[offsets],
                           block[self._row['coil_force_N'], offsets])

    def _lockstep_step(self, n: int, now_s: float, out: list) -> None:
        """Simulate ``n`` samples with the held coil setpoint: block, state, clock."""
        if self.queue.queued:
            setpoints, real = self.queue.pop(n)
        else:
            setpoints, real = np.zeros((2, n)), 0
        setpoints[0] += self.lock.coil_V
        first = self.next_index
        block = self._step(first, setpoints, out)
        out.append(MeasurementBlock(first, block))
        self.blocks_out += 1
        self.sim_samples = self.next_index
        if real:
            self._acknowledge(self.queue.head_index, now_s, out)
        # The state at t_k is the block's last sample, k N; stamped with simulated time.
        stamp_ns = int(round((self.next_index - 1) * 1e9 / self.rate))
        truth = block[self._row['position_true_m']]
        velocity = float((truth[-1] - truth[-2]) * self.rate) if n > 1 else 0.0
        state = JointStates(np.array([stamp_ns], dtype=np.int64),
                            np.array([self.last_position_m]), np.array([velocity]),
                            block[self._row['coil_force_N'], -1:].copy())
        self.lock.published(state, stamp_ns, now_s, n)
        out += [state, ClockTick(stamp_ns)]
        self.clocks_out += 1

    def _step(self, first: int, setpoints: np.ndarray, out: list) -> np.ndarray:
        """Simulate a block, applying the load schedule at its samples; count saturation."""
        n = setpoints.shape[1]
        parts, pos = [], 0
        for offset, entries in self.schedule.due(self.sim_samples, n):
            if offset > pos:
                parts.append(self.sim.step_block(setpoints[:, pos:offset]))
                pos = offset
            for _sample, mass, coupled in entries:
                out += self._apply_load(mass, self.coupled if coupled is None else coupled,
                                        first + pos, scheduled=True)
                at_s = (self.sim_samples + pos) / self.rate
                out.append(LogLine('info', f'load schedule: {mass!r} kg on the pan from sample '
                                           f'{first + pos} ({at_s:g} s simulated)'))
        parts.append(self.sim.step_block(setpoints[:, pos:]) if pos else
                     self.sim.step_block(setpoints))
        block = parts[0] if len(parts) == 1 else np.concatenate(parts, axis=1)
        self.next_index = first + n
        for key, count in saturation_counts(block, self.channel_names, self.sim.params).items():
            self.saturation[key] = self.saturation.get(key, 0) + count
        self.last_position_m = float(block[self._row['position_m'], -1])
        return block

    def _apply_load(self, mass_kg: float, coupled: bool, index: int,
                    scheduled: bool = False) -> list:
        self.sim.set_load(mass_kg, coupled)
        self.load_kg, self.coupled = float(mass_kg), bool(coupled)
        self.load_changes.append([int(index), float(mass_kg)])
        del self.load_changes[:-MAX_LOAD_CHANGES]
        return [DescriptionChanged(float(mass_kg) if scheduled else None)]

    def _acknowledge(self, index: int, now_s: float, out: list) -> None:
        """How far the excitation is consumed (repeated by :meth:`tick` if nothing follows)."""
        out.append(Acknowledgement(int(index)))
        self._ack = (int(index), float(now_s), 0)

    def _bad_command(self, reason: str, now_s: float) -> list:
        """Count and report a refused command; the session keeps running."""
        self.malformed += 1
        self.bad_commands += 1
        self.last_error = reason
        return self._warn('command', f'effort command refused: {reason}', now_s)

    def _warn(self, kind: str, text: str, now_s: float) -> list:
        last = self._warned.get(kind)
        if last is not None and now_s - last < THROTTLE_S[kind]:
            return []
        self._warned[kind] = float(now_s)
        return [LogLine('warning', text)]

    def _sim_time_ns(self) -> int:
        return int(round(self.sim_samples * 1e9 / self.rate))
