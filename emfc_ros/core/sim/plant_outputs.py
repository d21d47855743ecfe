"""
What a plant session reports: descriptions, diagnostics, readiness, published counts.

:class:`PlantOutputs` is a part of :class:`~emfc_ros.core.sim.plant_session.PlantSession`
(its state is the session's); :func:`locked` is the session's lock around a public method.
"""

from __future__ import annotations

import functools
from typing import Dict, Sequence, Tuple

from emfc_ros.core.blocks import Channel, StreamDescription
from emfc_ros.core.sim.channels import MEASURED, REFERENCE
from emfc_ros.core.sim.resolution import simulator_resolution


def locked(method):
    """
    Run a session method under the session's own (re-entrant) lock.

    Parameters
    ----------
    method : callable
        A method of the session (``self._mutex`` is its lock).

    Returns
    -------
    callable
        The method wrapped: it holds the lock while it runs.
    """
    @functools.wraps(method)
    def call(self, *args, **kwargs):
        with self._mutex:
            return method(self, *args, **kwargs)
    return call


class PlantOutputs:
    """The reports of a plant session (module docstring); mixed into it."""

    # -- outputs -------------------------------------------------------------------------

    @locked
    def descriptions(self, source: str) -> Dict[str, StreamDescription]:
        """
        The description of ``measurements`` and of each group stream.

        Parameters
        ----------
        source : str
            The publishing node's name.

        Returns
        -------
        dict
            Relative topic to its description.
        """
        meanings = {name: text for name, _unit, text in MEASURED + REFERENCE}
        channels = tuple(Channel(n, u, meanings.get(n, ''))
                         for n, u in zip(self.channel_names, self.channel_units))
        extra = {'time_mode': self.mode, 'load_mass_kg': self.load_kg,
                 'load_changer_coupled': self.coupled,
                 # [stream sample index, load [kg]] of the run-time changes, the latest last
                 'load_changes': [list(c) for c in self.load_changes]}
        if self.sim is not None:
            sim = getattr(self.sim, 'sim', self.sim)      # the closed loop's plant
            extra['resolution'] = {
                name: value for name, value in simulator_resolution(
                    sim.params, sim.noise, sim.quantisation,
                    getattr(self.sim, 'current_channel', None)).items()
                if name in self.channel_names}
        out = {'measurements': StreamDescription('measurements', self.rate, 0, channels,
                                                 epoch=self.epoch, source=source, extra=extra)}
        for group, rows in self.groups.items():
            out[f'measurements/{group}'] = StreamDescription(
                group, self.rate, 0, tuple(channels[i] for i in rows), epoch=self.epoch,
                source=source, extra=extra)
        return out

    @locked
    def diagnostics(self, now_s: float, flow_timeouts: int = 0,
                    holding: bool = False) -> Tuple[str, str, dict]:
        """
        The session's status: level (``OK``, ``WARN``, ``ERROR``), message and values.

        Parameters
        ----------
        now_s : float
            Monotonic time [s].
        flow_timeouts : int
            Owner mode: waits for the subscribers' acknowledgements that ended at their bound.
        holding : bool
            The node holds the excitation until ``min_subscribers`` matched.

        Returns
        -------
        tuple
            Level name, message and the key-value pairs of ``/diagnostics``.
        """
        values = dict(self.queue.counters())
        values.update({
            'time_mode': self.mode, 'sample_rate_Hz': self.rate,
            'simulated_samples': self.sim_samples,
            'simulated_time_s': f'{self.sim_samples / self.rate:.6f}',
            'wall_time_s': f'{now_s - self.start_s:.3f}',
            'blocks_in': self.blocks_in, 'blocks_out': self.blocks_out,
            'malformed_messages': self.malformed, 'command_N': self.command.effort_N,
            'command_watchdog_trips': self.command.watchdog_trips,
            'bad_commands': self.bad_commands,
            # the device contract's name (the daq_bridge's too)
            'command_malformed': self.bad_commands, 'last_error': self.last_error,
            'error': self.error, 'min_subscribers': self.config.min_subscribers,
            'states_published': self.states.published,
            'states_decimated': self.states.decimated,
            'acknowledgements_repeated': self.acks_repeated})
        if self.mode == 'lockstep':
            lock = self.lock
            wall = now_s - lock.first_wall_s if lock.started else 0.0
            values.update({
                'lockstep_samples_per_period': lock.period,
                'command_delay_periods': lock.delay, 'lockstep_match': lock.match,
                'lockstep_periods': lock.periods,
                'lockstep_periods_per_wall_s': f'{lock.periods / wall:.1f}' if wall else '0',
                'sim_time_per_wall_time': (f'{self.next_index / self.rate / wall:.4f}'
                                           if wall else '0'),
                'waiting_for_command': lock.waiting, 'states_republished': lock.republished,
                'stale_commands': lock.stale, 'unexpected_commands': lock.unexpected})
        values.update(self.saturation)
        defects = self.malformed + values['gaps'] + values['duplicates'] + \
            values['reordered'] + values['overlaps']
        level = 'WARN' if defects else 'OK'
        if self.sim is None or self.error:
            level = 'ERROR'
        message = self.error or ('excitation defects' if defects else 'ok')
        if level == 'OK' and flow_timeouts:
            level = 'WARN'
            message = (f'{flow_timeouts} wait(s) for acknowledgements by the subscribers '
                       'ended at the 2 s bound: a subscriber stalled or died (the simulation '
                       'slowed down; a subscriber that fell 100 blocks behind lost blocks)')
        if not self.error and holding:
            message = (f'waiting for {self.config.min_subscribers} subscription(s) to '
                       'measurements before subscribing to the excitation')
        return level, message, values

    @locked
    def readiness(self, holding: bool, topic: str, matched: int) -> Tuple[bool, str]:
        """
        Whether the excitation would be simulated, and what it waits for if not.

        Parameters
        ----------
        holding : bool
            The node holds the excitation until ``min_subscribers`` matched.
        topic : str
            The measurement topic (full name).
        matched : int
            Subscriptions matched on it [count].

        Returns
        -------
        tuple
            Ready, and the reason it is not ('' when ready).
        """
        if self.sim is None or self.error:
            return False, f'refuses to simulate: {self.error or "no simulator"}'
        if holding:
            return False, (f'waits for {self.config.min_subscribers} subscription(s) to '
                           f'{topic} (a recorder; {matched} matched)')
        return True, ''

    @locked
    def published_counts(self, block_topics: Sequence[str],
                         clock: bool) -> Dict[str, Dict[str, int]]:
        """
        Messages given to publish per stream, for an in-process supervisor's accounting.

        Parameters
        ----------
        block_topics : sequence of str
            The measurement topics (each carries every block).
        clock : bool
            Whether ``/clock`` is published.

        Returns
        -------
        dict
            Topic to ``published`` and, for ``joint_states``, ``decimated`` (left out by
            ``max_state_wall_rate_Hz``) [count]; lockstep states are not counted.
        """
        counts = {topic: {'published': self.blocks_out} for topic in block_topics}
        counts['joint_states'] = {'published': self.states.published,
                                  'decimated': self.states.decimated}
        if clock:
            counts['/clock'] = {'published': self.clocks_out}
        return counts
