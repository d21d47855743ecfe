"""
The bridge session's safety state machine: watchdog, emergency stop, safe outputs, faults.

:class:`SafetyPath` is a part of :class:`~emfc_ros.core.device.bridge_session.BridgeSession`
(its state is the session's): the excitation watchdog (outputs safe when the excitation
stopped for ``watchdog_timeout_s``), the latched emergency stop, the device's confirmation of
the safe outputs (a refusal stops the device), generator changes and restores, and the
latching of faults.
"""

from __future__ import annotations

from typing import Any, Dict, List, Sequence

from emfc_ros.core.device.errors import DeviceConfigError, DeviceError
from emfc_ros.core.device.faults import describe, Fault
from emfc_ros.core.device.function_generator import GeneratorSpec
from emfc_ros.core.excitation_queue import ExcitationQueue


#: A latched fault that grows is republished in the description at most this often [s].
GROWN_PERIOD_S = 1.0


class SafetyPath:
    """The safety state machine of a bridge session (module docstring); mixed into it."""

    # -- safety ------------------------------------------------------------------------------

    def _safe_specs(self) -> List[GeneratorSpec]:
        return [GeneratorSpec('constant', offset_V=float(v)) for v in self.safe]

    def _restore_generator(self) -> None:
        """The generator back to its configuration after a safe-output hold (worker)."""
        if self.state == 'running' and not self.estop:
            self._send_generator('function generator restored after a safe-output hold',
                                 'its outputs may still be at their safe values')

    def _send_generator(self, what: str, consequence: str) -> None:
        """Send the configured specs; a refusal is a ``generator_unconfirmed`` fault."""
        try:
            self.backend.set_function_generator(self.specs)
        except (DeviceError, DeviceConfigError) as exc:
            self._worker_fault('generator_unconfirmed', f'the device did not confirm the '
                               f'{what} ({exc}): {consequence}')

    def set_generator(self, specs: Sequence[GeneratorSpec]) -> None:
        """
        New generator specs (a run-time parameter change): sent by the worker when running.

        Parameters
        ----------
        specs : sequence of GeneratorSpec
            One per output, checked.
        """
        if self.settings.mode != 'function_generator':
            return
        self.specs = list(specs)
        if self.state == 'running' and not (self.estop or self.tripped):
            # Checked like the device checks it; sent by the worker thread (a refusal then
            # is a generator_unconfirmed fault).
            self._jobs.submit('set_generator', self._set_generator)

    def _set_generator(self) -> None:
        if self.state == 'running' and not (self.estop or self.tripped):
            self._send_generator('changed function generator',
                                 'it may still output the previous one')

    def _worker_fault(self, kind: str, message: str) -> None:
        """A fault the worker saw: latched by the caller's next tick."""
        self.last_error = message
        with self._lock:
            self._worker_faults.append((kind, self.device_index_now(), message, False))

    def _drive_safe(self, why: str) -> str:
        """
        Outputs to their safe values now: safe setpoints at once, the device's generator.

        The generator request (with its retries, seconds when the device is gone) runs in the
        worker thread, so the caller never waits for the device; a refusal is latched as a
        ``safe_outputs_unconfirmed`` fault and stops the device (STOP also drives the
        outputs safe), in the worker too.
        """
        with self._lock:
            self.queue = ExcitationQueue(self.safe)
            self.offset = None
            self.command.clear()
        index = self.device_index_now()
        self.counts[f'{why}_device_index'] = index
        self._jobs.submit('safe_outputs', self._confirm_safe, why)
        return f'outputs to {self.safe.tolist()} V from about device sample {index}'

    def _confirm_safe(self, why: str) -> None:
        if self.state != 'running':
            return                          # stopped meanwhile: STOP drove them safe
        try:
            self.backend.set_function_generator(self._safe_specs())
        except (DeviceError, DeviceConfigError) as exc:
            self._safe_failed = f'{why}: the device did not confirm the safe outputs ({exc})'
            return
        self.counts['safe_outputs_confirmed'] += 1

    def emergency_stop(self) -> str:
        """
        Outputs safe at once, latched until :meth:`reset`.

        Returns
        -------
        str
            What was done.
        """
        self.estop = True
        self.counts['emergency_stops'] += 1
        message = 'emergency stop latched until ~/reset: ' + self._drive_safe('emergency_stop')
        self._log('warning', message)
        if self.state == 'running':
            self._latch([self.monitor.add('emergency_stop',
                                          self.counts['emergency_stop_device_index'], None,
                                          'emergency stop: outputs at their safe values')])
        return message

    def reset(self) -> str:
        """
        Acknowledge the latched faults; release the emergency stop and a watchdog trip.

        Returns
        -------
        str
            What was done.
        """
        faults = self.monitor.faults
        if faults:
            # Acknowledged: the next data are clean again (the bag keeps the record).
            self.monitor.reset(self._health(), self.epoch or 0)
            self.publish_descriptions()
            self._log('info', f'{len(faults)} fault(s) acknowledged by ~/reset')
        if not self.estop and not self.tripped:
            return f'{len(faults)} fault(s) acknowledged' if faults else 'nothing to reset'
        self.estop = False
        self.tripped = False
        self._last_excitation = None
        if self.state == 'running':
            self._jobs.submit('restore_generator', self._restore_generator)
        return ('emergency stop released: outputs follow the excitation again (the generator '
                'is restored in the background)')

    def _health(self) -> Dict[str, Any]:
        try:
            return self.backend.health()
        except (DeviceError, OSError):
            return {}

    def _latch(self, faults: Sequence[Fault]) -> None:
        """Report newly latched faults: log, description, diagnostics, status."""
        if not faults:
            return
        self.counts['faults'] += len(faults)
        for line in describe(faults).splitlines():
            self._log('error', f'fault: {line}')
        self.publish_descriptions()
        self._out.diagnostics_due()
        self._out.status_changed()

    def tick(self) -> None:
        """The periodic safety check (every 10 ms): faults, device health, the watchdog."""
        if self.state != 'running':
            return
        with self._lock:
            found, self._worker_faults = self._worker_faults, []
        if found:
            self._latch([self.monitor.add(kind, index, None, message, exact)
                         for kind, index, message, exact in found])
        # the back-end's own findings (a driver error: its code and text), to the epoch's end
        reported = [self.monitor.add_reported(*f) for f in self.backend.take_faults()]
        self._latch([f for f in reported if f is not None])
        if self._safe_failed:
            message, self._safe_failed = self._safe_failed, ''
            self.last_error = message
            self._latch([self.monitor.add('safe_outputs_unconfirmed',
                                          self.device_index_now(), None, message)])
            self.request_stop()            # STOP drives the outputs safe (worker thread)
            return
        new = self.monitor.observe(self._health(), self.device_index_now(),
                                   self.last_end or 0, float(self.backend.silence_timeout_s))
        self._latch(new)
        # A latched fault that grew (an underrun going on) reaches the description, the
        # bag's record, at most once per GROWN_PERIOD_S.
        self._grown_pending = self.monitor.take_grown() or self._grown_pending
        now = self._now_s()
        if new:
            self._grown_at = now
        elif self._grown_pending and now - self._grown_at >= GROWN_PERIOD_S:
            self._grown_pending, self._grown_at = False, now
            self.publish_descriptions()
        if self.tripped or self.estop:
            return
        last = self._last_excitation
        if last is None or not any(not s.active for s in self.specs):
            return
        # From the last excitation block's arrival; once everything that arrived has been
        # written to the device, from when the device has played it, if that is later: a
        # short stream written whole well ahead is not cut before its end. Excitation still
        # queued in the bridge is cut at the trip, a fault (below).
        with self._lock:
            drained = self.queue.queued == 0
        written = self._exc_written_end
        if drained and written is not None and self._anchor_ns is not None:
            last = max(last, (self._anchor_ns + written * 1e9 / self.rate) * 1e-9)
        if self._now_s() - last > self.runtime['watchdog_timeout_s']:
            self.tripped = True
            self.counts['watchdog_trips'] += 1
            with self._lock:
                pending = self.queue.queued
                head = self.queue.head_index
            message = self._drive_safe('watchdog_trip')
            self._log('warning', f'excitation watchdog tripped: {message}')
            if pending:
                self._latch([self.monitor.add(
                    'excitation_watchdog', head, pending,
                    f'the excitation watchdog tripped with {pending} excitation samples '
                    'still queued: they were not applied')])
