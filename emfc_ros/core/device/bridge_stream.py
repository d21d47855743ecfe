"""
The bridge session's data path: device blocks in, setpoints out, excitation accepted.

:class:`StreamPath` is a part of :class:`~emfc_ros.core.device.bridge_session.BridgeSession`
(it holds no state of its own: the session's ``__init__`` and ``_reset_stream_state`` make
it): the measurement path (each device block published, then the setpoints written up to
``excitation_lead_s`` ahead and the excitation acknowledged), the excitation's acceptance,
offset and remap, and the effort command.
"""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

from emfc_ros.core.blocks import Block, Continuity
from emfc_ros.core.device.clock import earliest_start_ns
from emfc_ros.core.device.errors import DeviceConfigError, DeviceError
from emfc_ros.core.device_contract import (array_command_effort, CommandError,
                                           joint_command_effort, state_sample_offsets)
from emfc_ros.core.errors import BlockError
from emfc_ros.core.excitation_queue import DROPPED, ExcitationQueue
from emfc_ros.core.model.actuation import coil_setpoint_for_force_V

#: Excitation that arrives while the device is starting is kept for the start (at most this
#: many samples per output): mapped before START is confirmed it would be lost at the start.
EARLY_EXCITATION_MAX_SAMPLES = 1_000_000


class StreamPath:
    """The data path of a bridge session (module docstring); mixed into the session."""

    # -- measurement path --------------------------------------------------------------------

    def _read_loop(self) -> None:
        backend = self.backend
        while not self._reader_stop.is_set():
            try:
                block = backend.read_block(timeout_s=0.05)
            except Exception as exc:       # noqa: B902 a back-end failure must not kill us
                self.counts['reader_errors'] += 1
                self.last_error = f'read_block: {exc}'
                self._reader_stop.wait(0.1)
                continue
            if block is None:
                if backend.finished:
                    self._finished()
                    return
                continue
            try:
                self.on_device_block(block, self._clock_ns())
            except Exception as exc:       # noqa: B902 e.g. publishing during shutdown
                if self._reader_stop.is_set():
                    return
                self.counts['reader_errors'] += 1
                self.last_error = f'publishing a block: {exc}'

    def _finished(self) -> None:
        """A finite source (a replay) delivered its last block: state done, said once."""
        with self._lock:
            if self.state != 'running':
                return
            self._set_state('done')
        self._log('info', f'{self.backend.name} done: every block published (~/start '
                          'starts again in a new epoch)')

    def poll_host_paced(self) -> int:
        """
        Read the blocks a host-paced back-end has due by now (the caller's timer).

        Returns
        -------
        int
            Blocks read.
        """
        if self.state != 'running':
            return 0
        block = self.config.block_size
        due = int((self._now_s() - self._t_start) * self.rate)
        for n in range(64):
            if (self.last_end or 0) + block > due:
                return n
            got = self.backend.read_block(0.0)
            if got is None:
                return n
            self.on_device_block(got, self._clock_ns())
        return 64

    def on_device_block(self, block: Block, arrival_ns: int) -> None:
        """
        A measurement block from the device: publish it, then write setpoints and acknowledge.

        Parameters
        ----------
        block : Block
            The block, with the device's sample indices and epoch.
        arrival_ns : int
            When it arrived (``clock_ns``) [ns].
        """
        if block.samples.ndim != 2 or block.samples.shape[0] != len(self.config.inputs) or \
                block.n_samples < 1:
            self.counts['malformed_blocks'] += 1
            self.last_error = f'device block of shape {block.samples.shape} dropped'
            return
        with self._lock:
            new_epoch = block.epoch != self.epoch
            if new_epoch:
                self.epoch = block.epoch
                self._expected = None
                self.last_end = None
                self._write_index = None
                self._exc_written_end = None
                self.offset = None            # the device index restarted: remap
                self._device_restarted = self._exc_received_end > 0
                self.queue = ExcitationQueue(self.safe)
                self._anchor_ns = arrival_ns - int(block.end_index * 1e9 / self.rate)
                self.counts['epoch_changes'] += 1
                self.monitor.set_epoch(block.epoch)     # faults count in the new epoch
            else:
                # The device clock's start is known no earlier than the earliest arrival says:
                # a first block that arrived late (a stall) must not leave the estimate of the
                # device index behind for the run (setpoints written late by that much).
                self._anchor_ns = earliest_start_ns(self._anchor_ns, arrival_ns,
                                                    block.end_index, self.rate)
            if self._expected is not None:
                if block.first_sample_index < self._expected:
                    self.counts['dropped_out_of_order_blocks'] += 1
                    return
                if block.first_sample_index > self._expected:
                    self.counts['published_gaps'] += 1
                    self.counts['published_missing_samples'] += \
                        block.first_sample_index - self._expected
            self._expected = block.end_index
            self.last_end = block.end_index
        if new_epoch:
            self.publish_descriptions()
        self._out.publish_block(block)
        done = self._clock_ns()
        self._latency_ns.append(done - arrival_ns)
        self._age_ns.append(done - self._anchor_ns - int(block.end_index * 1e9 / self.rate))
        self.counts['published_blocks'] += 1
        self.counts['published_samples'] += block.n_samples
        self._write_setpoints(block.end_index)
        self._acknowledge(block.end_index)
        self._states(block)

    def _states(self, block: Block) -> None:
        """The lever's position, velocity and coil force at the joint-state samples."""
        rate = self.runtime['state_rate_Hz']
        s, n, rows, balance = block.samples, block.n_samples, self.rows, self.settings.balance
        # without joint states only the last sample's position is needed
        s_pos = s if rate > 0.0 else s[:, -1:]
        if 'position_m' in rows:
            position = s_pos[rows['position_m']]
        elif 'sensor_V' in rows:
            position = np.asarray(balance.sensor.position_m(s_pos[rows['sensor_V']]))
        else:
            position = np.full(s_pos.shape[1], np.nan)
        # the effort command's setpoint depends on it, with or without joint states
        self.last_position_m = float(position[-1]) if np.isfinite(position[-1]) else 0.0
        if rate <= 0.0:
            return
        velocity = np.gradient(position) * self.rate if n > 1 else np.zeros(n)
        if 'coil_force_N' in rows:
            effort = s[rows['coil_force_N']]
        elif 'coil_current_A' in rows:
            effort = np.asarray(balance.motor.force_N(s[rows['coil_current_A']], position))
        else:
            effort = np.full(n, np.nan)
        at = state_sample_offsets(block.first_sample_index, n, self.rate, rate)
        if len(at):
            stamps = self._start_time_ns + np.rint(
                (block.first_sample_index + at) * 1e9 / self.rate).astype(np.int64)
            self._out.publish_states(stamps, position[at], velocity[at], effort[at])
            self.counts['published_states'] += len(at)

    # -- setpoint path -----------------------------------------------------------------------

    def _command_V(self) -> float:
        effort = self.command.value(self._now_s(), self.runtime['command_timeout_s'])
        if effort == 0.0:
            return 0.0
        return coil_setpoint_for_force_V(self.settings.balance, effort, self.last_position_m)

    def _write_setpoints(self, device_end: int) -> None:
        """Write setpoints for the device samples up to ``device_end + lead``."""
        with self._lock:
            command = self._command_V()
            halted = self.estop or self.tripped
            if self.offset is None and command == 0.0 and not halted and \
                    self._write_index is None:
                # nothing streamed yet: the device holds safe. Once streaming, the safe
                # values go on (a stream that stopped would run the device dry: an underrun)
                return
            target = device_end + self._lead_samples()
            w = self._write_index if self._write_index is not None else device_end
            if w < device_end:
                self.counts['setpoint_late_samples'] += device_end - w
                w = device_end
            n = target - w
            if n <= 0:
                return
            out = np.repeat(self.safe[:, None], n, axis=1)
            q = self.queue
            if self.offset is not None and not halted:
                if q.queued and q.head_index < w:
                    late = min(w - q.head_index, q.queued)
                    self._late_fault(q.head_index, late)
                    q.pop(late)
                    self.counts['excitation_late_samples'] += late
                lead = max(0, q.head_index - w)
                if lead < n:
                    samples, real = q.pop(n - lead)
                    out[:, lead:] = samples
                    if real:
                        self._exc_written_end = w + lead + real
            if command and not halted:
                out[0] += command
                clipped = int(np.count_nonzero((out < self._lo) | (out > self._hi)))
                if clipped:
                    self.counts['clamped_samples'] += clipped
                    np.clip(out, self._lo, self._hi, out=out)
            self._write_index = target
        try:
            self.backend.write_setpoints(w, out)
            self.counts['setpoint_samples_written'] += n
        except (DeviceError, DeviceConfigError) as exc:
            self.counts['setpoint_write_errors'] += 1
            self.last_error = f'write_setpoints: {exc}'

    def _late_fault(self, device_index: int, samples: int) -> None:
        """Excitation that came after its device samples were written: a fault (lock held)."""
        if self.monitor.has('excitation_late') or \
                any(f[0] == 'excitation_late' for f in self._worker_faults):
            return
        lead_s = self.runtime['excitation_lead_s']
        self._worker_faults.append((
            'excitation_late', int(device_index),
            f'{samples} excitation samples arrived after their device samples had been '
            f'written (from device sample {device_index}): the generator, or the link to it, '
            f'was more than excitation_lead_s ({lead_s:g} s) behind the device, or a '
            "consumer-paced generator's window is shorter than that lead; the outputs were at "
            'their safe values there', True))

    def _acknowledge(self, device_end: int) -> None:
        with self._lock:
            if self.offset is None:
                return
            consumed = min(device_end - self.offset, self._exc_received_end)
        if consumed > self._acked and consumed >= 0:
            self._acked = consumed
            self._out.publish_consumed(int(consumed))

    # -- excitation in -----------------------------------------------------------------------

    def on_excitation(self, block: Block) -> None:
        """
        An excitation block: checked, clamped, queued for the device (or held, or refused).

        Parameters
        ----------
        block : Block
            Setpoint voltages [V], one row per output, in the excitation's own indices.
        """
        try:
            if block.samples.ndim != 2 or block.samples.shape[0] != len(self.config.outputs):
                raise BlockError(f'excitation block has {block.samples.shape[0]} channels, '
                                 f'the device has {len(self.config.outputs)} outputs')
            if abs(block.sample_rate_Hz - self.rate) > 1e-9 * self.rate:
                raise BlockError(f'excitation at {block.sample_rate_Hz} Hz, the device runs '
                                 f'at {self.rate} Hz')
            if block.n_samples == 0:
                raise BlockError('excitation block has no samples')
            if not np.all(np.isfinite(block.samples)):
                raise BlockError('excitation block holds NaN or infinite values')
        except BlockError as exc:
            self.refuse_excitation(str(exc))
            return
        samples = np.array(block.samples, dtype=np.float64)
        clipped = int(np.count_nonzero((samples < self._lo) | (samples > self._hi)))
        if clipped:
            np.clip(samples, self._lo, self._hi, out=samples)
        with self._lock:
            if self.state != 'running':
                self._hold_excitation(block, samples, clipped)
                return
        self._take_excitation(block, samples, clipped)

    def refuse_excitation(self, reason: str) -> None:
        """
        A malformed excitation message: counted, said, dropped.

        Parameters
        ----------
        reason : str
            What is wrong with it.
        """
        self.counts['excitation_malformed'] += 1
        self.last_error = reason
        self._log('warning', f'excitation block dropped: {reason}', 5.0, 'refused')

    def _hold_excitation(self, block: Block, samples: np.ndarray, clipped: int) -> None:
        """Excitation before the device runs: kept for the start, or dropped and counted."""
        held = sum(b.n_samples for b, _, _ in self._early)
        if self.state == 'starting' and held + block.n_samples <= EARLY_EXCITATION_MAX_SAMPLES:
            self._early.append((block, samples, clipped))
            return
        self.counts['excitation_not_running'] += 1
        self.last_error = (f'excitation block at sample {block.first_sample_index} dropped: the '
                           f'device is not running (state {self.state})')
        self._log('warning', self.last_error, 5.0, 'not_running')

    def _take_excitation(self, block: Block, samples: np.ndarray, clipped: int) -> None:
        """Queue an excitation block for the device (the device runs)."""
        remap = False
        with self._lock:
            try:
                self._jump_guard.check(self._exc_tracker, block)
            except BlockError as exc:
                self.refuse_excitation(str(exc))
                return
            kind = self._exc_tracker.observe(block.first_sample_index, block.n_samples,
                                             block.epoch)
            if kind in DROPPED:
                # Counted by the tracker. A block we already have: its sender did not hear
                # our acknowledgement, so say again how far we are.
                if self._acked > 0 and self.offset is not None:
                    self._out.publish_consumed(int(self._acked))
                return
            self.counts['excitation_blocks'] += 1
            self.counts['clamped_samples'] += clipped
            self._last_excitation = self._now_s()
            if self.tripped and not self.estop:         # a latched e-stop keeps it safe
                self.tripped = False
                self._jobs.submit('restore_generator', self._restore_generator)
                if kind not in (Continuity.FIRST, Continuity.RESTART):
                    # The same stream goes on after a gap the outputs spent at their safe
                    # values: the samples between were not applied.
                    self._latch([self.monitor.add(
                        'excitation_watchdog', self.counts.get('watchdog_trip_device_index'),
                        None, 'the excitation stopped for longer than watchdog_timeout_s '
                        'and then went on: the outputs were at their safe values in between '
                        'and the rest is applied with a new offset')])
            if self.estop:
                self.counts['excitation_dropped_estop'] += 1
                return                          # latched: nothing is queued until ~/reset
            if kind in (Continuity.FIRST, Continuity.RESTART) or self.offset is None:
                start = self.device_index_now() + self._lead_samples()
                if self._write_index is not None:
                    start = max(start, self._write_index)
                self.offset = start - block.first_sample_index
                restarted, self._device_restarted = self._device_restarted, False
                if block.first_sample_index > 0 and \
                        (kind in (Continuity.FIRST, Continuity.RESTART) or restarted):
                    # The device applies this epoch's excitation from here on: what came
                    # before it was not applied (or in an earlier device epoch). A remap
                    # after safe outputs (watchdog, e-stop) is that fault's, not this one.
                    # Recorded at the device index sample 0 would have had, spanning the
                    # samples never applied: experiment samples 0 to first - 1.
                    self._latch([self.monitor.add(
                        'excitation_start_missing', self.offset, block.first_sample_index,
                        f'the excitation is applied from its sample '
                        f'{block.first_sample_index} on (device sample {start}): its samples '
                        f'0 to {block.first_sample_index - 1} never reached the device in this '
                        'device epoch, so the recorded excitation before them was not applied',
                        True)])
                self.queue = ExcitationQueue(self.safe)
                self._acked = -1
                remap = True
            self._exc_received_end = block.end_index
            self.queue.push(Block(block.first_sample_index + self.offset, self.rate, 0,
                                  samples))
        if remap:
            self.publish_descriptions()

    # -- effort commands ---------------------------------------------------------------------

    def on_command(self, effort_N: Optional[float], problem: str = '') -> None:
        """
        An effort command [N], or a refused one (``effort_N`` None and the problem).

        Parameters
        ----------
        effort_N : float or None
            The coil force to add [N] (checked by the device contract's parsers).
        problem : str
            Why a command was refused.
        """
        if effort_N is None:
            self.counts['command_malformed'] += 1
            self.last_error = problem
            return
        with self._lock:
            self.command.set(effort_N, self._now_s())

    def on_joint_command(self, names: Sequence[str], efforts: Sequence[float]) -> None:
        """
        A ``joint_commands`` message: the effort of joint ``lever`` [N], or a refusal.

        Parameters
        ----------
        names, efforts : sequence
            The message's joint names and efforts [N].
        """
        try:
            self.on_command(joint_command_effort(names, efforts))
        except CommandError as exc:
            self.on_command(None, str(exc))

    def on_array_command(self, data: Sequence[float]) -> None:
        """
        A ``commands`` message: exactly one effort [N], or a refusal.

        Parameters
        ----------
        data : sequence of float
            The message's data.
        """
        try:
            self.on_command(array_command_effort(data))
        except CommandError as exc:
            self.on_command(None, str(exc))
