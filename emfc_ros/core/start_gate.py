"""
When a signal generator may send sample 0: start gates that name what they wait for.

The node that applies the excitation (the ``plant_simulator``, the ``daq_bridge``) announces
on the latched topic ``excitation/ready`` whether it can apply excitation now, and if not,
what it waits for (:class:`Readiness`; a JSON text on ``std_msgs/String``). A generator
whose gate is ``applier`` holds sample 0 until an applier announced ready, that applier's
subscription to the excitation is in the graph, and every subscription the graph lists is
matched by the generator's publisher, so that no sample goes to a reader that is not yet
matched; ``min_subscribers`` adds a count on top (a recorder of the excitation). The gate
``subscribers`` is the count alone; ``none`` opens at once.

Pure: the caller (the node) passes the announcements, the graph's subscriptions and the
publisher's matched count. ``docs/decisions.md`` (Start gates) says why.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import json
from typing import Dict, Iterable, Sequence, Tuple

from emfc_ros.core.errors import EmfcError

#: Gate kinds (the generator's ``start_gate`` parameter; ``auto`` is resolved by the node).
GATES = ('applier', 'subscribers', 'none')


class ReadinessError(EmfcError, ValueError):
    """A readiness announcement that does not parse."""


@dataclass(frozen=True)
class Readiness:
    """
    An applier's announcement on ``excitation/ready``.

    Attributes
    ----------
    node : str
        Fully qualified name of the announcing node (``/emfc/daq_bridge``).
    ready : bool
        Whether it applies excitation that arrives now.
    waiting : str
        When not ready: why, as a predicate of the node (``'waits for the device to
        start'``, ``'refuses to simulate: ...'``).
    """

    node: str
    ready: bool
    waiting: str = ''

    def to_json(self) -> str:
        """
        The announcement as the topic carries it.

        Returns
        -------
        str
            A JSON object with ``node``, ``ready`` and ``waiting``.
        """
        return json.dumps({'node': self.node, 'ready': self.ready, 'waiting': self.waiting})

    @classmethod
    def from_json(cls, text: str) -> 'Readiness':
        """
        Parse an announcement.

        Parameters
        ----------
        text : str
            The JSON text.

        Returns
        -------
        Readiness
            The announcement.

        Raises
        ------
        ReadinessError
            If the text is not a JSON object with a string ``node`` and a boolean ``ready``.
        """
        try:
            doc = json.loads(text)
        except (TypeError, ValueError) as exc:
            raise ReadinessError(f'readiness is not JSON: {exc}') from exc
        if not isinstance(doc, dict):
            raise ReadinessError(f'readiness is a JSON object, got {type(doc).__name__}')
        node, ready, waiting = doc.get('node'), doc.get('ready'), doc.get('waiting', '')
        if not isinstance(node, str) or not node.startswith('/'):
            raise ReadinessError(f'readiness needs the fully qualified node name, got {node!r}')
        if not isinstance(ready, bool):
            raise ReadinessError(f'readiness needs ready: true or false, got {ready!r}')
        if not isinstance(waiting, str):
            raise ReadinessError(f'readiness waiting is text, got {waiting!r}')
        return cls(node, ready, waiting)


@dataclass(frozen=True)
class Subscription:
    """
    A subscription to the excitation as the graph lists it.

    Attributes
    ----------
    node : str
        Fully qualified name of its node.
    compatible : bool
        Whether its QoS can match the generator's publisher (a transient-local reader
        never matches a volatile writer; such a reader is not waited for).
    """

    node: str
    compatible: bool = True


@dataclass
class StartGate:
    """
    Decide whether sample 0 may go.

    Parameters
    ----------
    kind : str
        ``'applier'``, ``'subscribers'`` or ``'none'`` (:data:`GATES`).
    min_subscribers : int
        Matched subscriptions needed in any case [count] (0: none beyond the applier's).

    Raises
    ------
    ValueError
        For an unknown kind or a negative count.
    """

    kind: str
    min_subscribers: int = 0
    announcements: Dict[str, Readiness] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.kind not in GATES:
            raise ValueError(f'start_gate must be one of {list(GATES)}, got {self.kind!r}')
        if isinstance(self.min_subscribers, bool) or int(self.min_subscribers) < 0:
            raise ValueError(f'min_subscribers must be a count >= 0, got '
                             f'{self.min_subscribers!r}')
        self.min_subscribers = int(self.min_subscribers)

    def announce(self, readiness: Readiness) -> None:
        """
        Keep an applier's latest announcement.

        Parameters
        ----------
        readiness : Readiness
            The announcement.
        """
        self.announcements[readiness.node] = readiness

    def waiting_for(self, subscriptions: Iterable[Subscription], matched: int) -> str:
        """
        What sample 0 waits for, or '' when it may go now.

        Parameters
        ----------
        subscriptions : iterable of Subscription
            The excitation's subscriptions the graph lists (other nodes' and our own).
        matched : int
            Subscriptions matched by the generator's publisher [count].

        Returns
        -------
        str
            Empty when the gate is open; otherwise what it waits for, in words (names the
            applier and what the applier itself waits for).
        """
        if self.kind == 'none':
            return ''
        subs = [s for s in subscriptions if s.compatible]
        missing = []
        if self.kind == 'applier':
            missing += self._applier_missing(subs, matched)
        if matched < self.min_subscribers:
            missing.append(f'{self.min_subscribers} subscription(s) to the excitation '
                           f'({matched} matched)')
        return ' and '.join(missing)

    def _applier_missing(self, subs: Sequence[Subscription], matched: int) -> list:
        nodes = {s.node for s in subs}
        announced = sorted(self.announcements.values(), key=lambda r: r.node)
        ready = [r for r in announced if r.ready and r.node in nodes]
        if not ready:
            if not announced:
                return ['the node that applies the excitation (the plant_simulator or the '
                        'daq_bridge, announcing ready on excitation/ready)']
            return [f'{r.node} to be ready (it {r.waiting or "is not ready"})' if not r.ready else
                    f'the subscription of {r.node} (ready) to the excitation to appear'
                    for r in announced]
        if matched < len(subs):
            return [f'{len(subs)} subscription(s) to the excitation to match, '
                    f'{ready[0].node} among them ({matched} matched)']
        return []


def parse_endpoints(endpoints: Iterable[Tuple[str, str, bool]]) -> Tuple[Subscription, ...]:
    """
    Subscriptions from ``(namespace, name, transient_local)`` triples of the graph.

    Parameters
    ----------
    endpoints : iterable of tuple
        Node namespace, node name and whether the reader asks for transient-local durability.

    Returns
    -------
    tuple of Subscription
        With fully qualified node names.
    """
    out = []
    for namespace, name, transient_local in endpoints:
        fqn = (namespace.rstrip('/') + '/' + name) if namespace else '/' + name
        out.append(Subscription(fqn, compatible=not transient_local))
    return tuple(out)


def resolve_gate(value: str, pacing: str) -> str:
    """
    The gate a ``start_gate`` parameter value means.

    Parameters
    ----------
    value : str
        ``'auto'`` or one of :data:`GATES`.
    pacing : str
        ``'wall'`` or ``'consumer'``.

    Returns
    -------
    str
        ``auto``: ``applier`` for consumer pacing (its consumer is the applier),
        ``subscribers`` for wall pacing (a generator alone streams at once).

    Raises
    ------
    ValueError
        For another value.
    """
    if value == 'auto':
        return 'applier' if pacing == 'consumer' else 'subscribers'
    if value not in GATES:
        raise ValueError(f"start_gate must be 'auto' or one of {list(GATES)}, got {value!r}")
    return value


def readiness_text(node: str, ready: bool, waiting: str = '') -> str:
    """
    The JSON an applier publishes on ``excitation/ready``.

    Parameters
    ----------
    node : str
        Its fully qualified name.
    ready : bool
        Whether excitation arriving now is applied.
    waiting : str
        What it waits for when not ready.

    Returns
    -------
    str
        The text (:meth:`Readiness.to_json`).
    """
    return Readiness(node, bool(ready), '' if ready else waiting).to_json()
