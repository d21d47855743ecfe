"""
The bookkeeping of the lockstep time mode: one controller period per effort command.

The plant publishes the state at ``t_k`` and waits; a command answers it when it is the one
that state asked for (the same header stamp with ``match: stamp``, any with ``match: next``
or from a topic without stamps). :class:`Lockstep` decides which command answers and which
coil setpoint holds over the next period (``delay`` 1: the one of the command before).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from emfc_ros.core.sim.plant_events import JointStates


@dataclass
class Lockstep:
    """
    State and counters of the lockstep mode.

    Attributes
    ----------
    period : int
        Samples per controller period; 0: not configured (the mode refuses to step).
    delay : int
        ``command_delay_periods`` (0 or 1).
    match : str
        ``lockstep_match``: ``stamp`` or ``next``.
    """

    period: int = 0
    delay: int = 1
    match: str = 'stamp'
    started: bool = False           # the first state has been published
    waiting: bool = False           # a state is published and waits for its command
    stamp_ns: int = 0               # stamp of the state waiting for its command [ns]
    published_at_s: float = 0.0     # monotonic time that state was (re-)published [s]
    state: Optional[JointStates] = None
    hold_V: Optional[float] = None  # coil setpoint before the first command [V]
    coil_V: float = 0.0             # coil setpoint held over the current period [V]
    pending_V: float = 0.0          # delay 1: setpoint of the next period [V]
    periods: int = 0                # periods simulated
    republished: int = 0            # states re-published for lack of an answer
    stale: int = 0                  # joint_commands whose stamp matches no waiting state
    unexpected: int = 0             # commands while no state waits (before the start)
    first_wall_s: float = 0.0       # monotonic time of the first state [s]

    def start(self, hold_V: float, now_s: float) -> None:
        """
        Start at the hold point: the first period holds ``hold_V``.

        Parameters
        ----------
        hold_V : float
            The coil setpoint that holds the lever at the operating point [V].
        now_s : float
            Monotonic time [s].
        """
        self.started = True
        self.first_wall_s = float(now_s)
        self.hold_V = self.coil_V = self.pending_V = float(hold_V)

    def answers(self, stamp_ns: Optional[int]) -> bool:
        """
        Whether a command with ``stamp_ns`` answers the waiting state (counted if not).

        Parameters
        ----------
        stamp_ns : int or None
            The command's header stamp [ns]; None: a command without one.

        Returns
        -------
        bool
            True: the state is answered (no longer waiting).
        """
        if not self.waiting:
            self.unexpected += 1
            return False
        if stamp_ns is not None and self.match == 'stamp' and stamp_ns != self.stamp_ns:
            self.stale += 1         # answers an earlier (or no) state: ignored
            return False
        self.waiting = False
        return True

    def command(self, coil_V: float) -> None:
        """
        The coil setpoint of an answering command [V]: now, or one period later.

        Parameters
        ----------
        coil_V : float
            The setpoint that gives the commanded force [V].
        """
        if self.delay == 0:
            self.coil_V = float(coil_V)
        else:
            self.coil_V, self.pending_V = self.pending_V, float(coil_V)

    def back_to_hold(self) -> None:
        """After a reset: hold the hold point again (when started)."""
        if self.hold_V is not None:
            self.coil_V = self.pending_V = self.hold_V

    def published(self, state: JointStates, stamp_ns: int, now_s: float, n: int) -> None:
        """
        A state was published after ``n`` samples and waits for its command.

        Parameters
        ----------
        state : JointStates
            The state (one entry).
        stamp_ns : int
            Its stamp [ns].
        now_s : float
            Monotonic time [s].
        n : int
            Samples the step simulated.
        """
        self.state, self.stamp_ns, self.waiting = state, int(stamp_ns), True
        self.periods += 1 if n == self.period else 0
        self.published_at_s = float(now_s)

    def republish_due(self, now_s: float, timeout_s: float) -> bool:
        """
        Whether the waiting state is to be published again (counted when it is).

        Parameters
        ----------
        now_s : float
            Monotonic time [s].
        timeout_s : float
            Wall time without an answer after which it is [s].

        Returns
        -------
        bool
            True: publish ``state`` again now.
        """
        if not self.waiting or now_s - self.published_at_s < timeout_s:
            return False
        self.republished += 1
        self.published_at_s = float(now_s)
        return True
