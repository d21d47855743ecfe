"""The start gate's rule: sample 0 waits for the applier, named, whatever else subscribes."""

import pytest

from emfc_ros.core.start_gate import (parse_endpoints, Readiness, readiness_text,
                                      ReadinessError, resolve_gate, StartGate, Subscription)

BRIDGE = '/emfc/daq_bridge'
RECORDER = '/emfc/recorder'


def gate(kind='applier', count=0, *announcements):
    g = StartGate(kind, count)
    for a in announcements:
        g.announce(a)
    return g


def test_a_recorder_alone_never_opens_the_applier_gate():
    """The issue's failure: the recorder's subscription opened a count of 1."""
    subs = [Subscription(RECORDER)]
    assert gate('subscribers', 1).waiting_for(subs, 1) == ''           # the old rule opens
    waiting = gate('applier', 1).waiting_for(subs, 1)
    assert waiting.startswith('the node that applies the excitation')
    # announced, not ready: what it waits for is named
    not_ready = Readiness(BRIDGE, False, 'waits for the device to start')
    waiting = gate('applier', 1, not_ready).waiting_for(subs, 1)
    assert waiting == f'{BRIDGE} to be ready (it waits for the device to start)'
    # ready, but its subscription not in the graph yet
    ready = Readiness(BRIDGE, True)
    waiting = gate('applier', 1, ready).waiting_for(subs, 1)
    assert waiting == f'the subscription of {BRIDGE} (ready) to the excitation to appear'


def test_the_applier_gate_opens_only_once_every_listed_subscription_matched():
    ready = Readiness(BRIDGE, True)
    subs = [Subscription(RECORDER), Subscription(BRIDGE)]
    g = gate('applier', 0, ready)
    assert '2 subscription(s) to the excitation to match' in g.waiting_for(subs, 1)
    assert g.waiting_for(subs, 2) == ''
    # min_subscribers on top (the applier and a recorder of the excitation)
    assert g.waiting_for(subs[1:], 1) == ''
    assert gate('applier', 2, ready).waiting_for(subs[1:], 1) == \
        '2 subscription(s) to the excitation (1 matched)'
    # a transient-local reader never matches a volatile writer: not waited for
    subs_tl = [Subscription(BRIDGE), Subscription('/x/echo', compatible=False)]
    assert g.waiting_for(subs_tl, 1) == ''


def test_the_latest_announcement_counts_and_other_kinds():
    g = gate('applier', 0, Readiness(BRIDGE, True))
    g.announce(Readiness(BRIDGE, False, 'refuses: start failed: no answer'))
    assert 'refuses: start failed' in g.waiting_for([Subscription(BRIDGE)], 1)
    assert gate('none', 5).waiting_for([], 0) == ''
    assert gate('subscribers', 2).waiting_for([], 1) == \
        '2 subscription(s) to the excitation (1 matched)'
    with pytest.raises(ValueError, match='start_gate must be one of'):
        StartGate('sometimes')
    with pytest.raises(ValueError, match='count >= 0'):
        StartGate('applier', -1)


def test_auto_resolves_by_pacing():
    assert resolve_gate('auto', 'consumer') == 'applier'
    assert resolve_gate('auto', 'wall') == 'subscribers'
    assert resolve_gate('none', 'consumer') == 'none'
    with pytest.raises(ValueError):
        resolve_gate('later', 'wall')


def test_readiness_round_trip_and_malformed_text():
    text = readiness_text(BRIDGE, False, 'waits for the device to start')
    assert Readiness.from_json(text) == Readiness(BRIDGE, False, 'waits for the device to start')
    assert Readiness.from_json(readiness_text(BRIDGE, True, 'ignored')).waiting == ''
    for bad in ('', '[1]', '{"node": "x", "ready": true}', '{"node": "/a", "ready": 1}',
                '{"node": "/a", "ready": true, "waiting": 3}'):
        with pytest.raises(ReadinessError):
            Readiness.from_json(bad)


def test_graph_endpoints_become_fully_qualified_names():
    subs = parse_endpoints([('/emfc', 'daq_bridge', False), ('/', 'echo', True),
                            ('', 'bare', False)])
    assert subs == (Subscription(BRIDGE), Subscription('/echo', False),
                    Subscription('/bare'))
