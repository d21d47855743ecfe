"""
The suite on two computers, as the README's "Two computers" section runs it.

Two network namespaces (each with its own ``/dev/shm``, so that Fast DDS cannot use shared
memory between them) joined by a veth pair with the README's addresses stand for the two
computers: the README's bridge-computer lines (device emulator, daq_bridge) run in one, its
recording-computer lines (recorder, signal generator, then ``emfc-identify``) in the other,
each line as typed (``ros2 run`` resolved as ``ros2 run`` resolves it; the exported
variables as given, except ``ROS_DOMAIN_ID``, which is this session's). A frame capture on
the link and the interface counters show what crossed it: discovery by unicast between the
two addresses only, no multicast, the data across the link, the device's UDP on the bridge
computer's loopback. Then the same lines run on one "computer" (one namespace, without
``ROS_STATIC_PEERS``), and the two bags, read with the independent ``mcap`` reader, are
compared sample for sample: the measurements lined up on the excitation (the device's
sample offset of the excitation differs from run to run) and the excitation by sample index.
The emulator runs without noise, so both runs give the same samples wherever the
excitation starts on the device clock.

Needs root and iproute2 (the CI runs as root; ``tools/setup_env.sh`` installs iproute2):
without them the test fails saying so, it never skips.
"""

import json
import os
from pathlib import Path
import re
import shlex
import sys

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
import yaml

from emfc_ros.core.signals import load_experiment_file
import netns_hosts
import ros_harness
from ros_harness import scaled

REPO = Path(__file__).resolve().parents[2]
SHARE_CONFIG = Path(sys.prefix, 'share', 'emfc_ros', 'config')
NAMESPACE = '/emfc'
#: A fresh install compiles the simulator kernel at the emulator's first start (about 15 s).
START_TIMEOUT_S = scaled(240.0)
STOP_TIMEOUT_S = scaled(30.0)
IDENTIFY_TIMEOUT_S = scaled(300.0)
#: Measured after the last excitation sample before the recorder is stopped [samples].
SETTLE_SAMPLES = 2000
DAC_LSB_V = 20.0 / 65536
LINK = 'emfc0'
PREFIX = 30


# -- the README's lines -------------------------------------------------------------------


def readme_blocks():
    """
    The two shell blocks of the "Two computers" page (docs/two_computers.md).

    Returns
    -------
    list of list of str
        Per block its lines, continuation lines joined.
    """
    text = (REPO / 'docs' / 'two_computers.md').read_text()
    assert text.startswith('# Two computers\n'), 'docs/two_computers.md is not that page'
    blocks = re.findall(r'```bash\n(.*?)```', text, re.S)
    assert len(blocks) == 2, f'expected two bash blocks (bridge, recording), got {len(blocks)}'
    return [block.replace('\\\n', '').splitlines() for block in blocks]


def parse_block(lines):
    """
    Exported variables and commands of one block, as the shell splits them.

    Returns
    -------
    (dict, list of list of str)
        The ``export`` assignments and the commands (comments dropped).
    """
    env, commands = {}, []
    for line in lines:
        words = shlex.split(line, comments=True)
        if not words:
            continue
        if words[0] == 'export':
            for word in words[1:]:
                name, value = word.split('=', 1)
                env[name] = value
        else:
            commands.append(words)
    return env, commands


def argv_of(words):
    """The command a user's shell runs for a README line (``ros2 run`` or ``emfc-*``)."""
    if words[:2] == ['ros2', 'run']:
        assert words[2] == 'emfc_ros', words
        return [str(ros_harness.resolve_ros2run('emfc_ros', words[3]))] + words[4:]
    if words[0].startswith('emfc-'):
        path = Path(sys.executable).parent / words[0]
        assert path.is_file(), f'{words[0]} is not installed in {path.parent}'
        return [str(path)] + words[1:]
    raise AssertionError(f'the test does not know how to run README line {words}')


def host_environment(exports, drop=()):
    """This process's environment with the README's exports (domain id: the session's)."""
    env = dict(os.environ)
    env.pop('ROS_STATIC_PEERS', None)
    env.update(exports)
    for name in drop:
        env.pop(name, None)
    env['ROS_DOMAIN_ID'] = str(ros_harness.session_domain_id())
    env['PYTHONUNBUFFERED'] = '1'
    env['PATH'] = os.pathsep.join([str(Path(sys.executable).parent), env.get('PATH', '')])
    return env


def workdir(path):
    """A working directory with ``config/`` as in a checkout (the installed config files)."""
    path.mkdir(parents=True)
    (path / 'config').symlink_to(SHARE_CONFIG, target_is_directory=True)
    return path


# -- one run ------------------------------------------------------------------------------


class Observer:
    """The observer process's JSON lines, newest value per key."""

    def __init__(self, process):
        self.process = process

    def state(self):
        out = {}
        for line in self.process.output().splitlines():
            if line.startswith('{'):
                try:
                    out.update(json.loads(line))
                except json.JSONDecodeError:
                    pass                        # a line being written
        return out


def experiment_run(bridge_host, recording_host, bridge_env, recording_env, bridge_dir,
                   recording_dir, logs, total, identify):
    """
    Run the README's lines: bridge block on one host, recording block on the other.

    Returns
    -------
    dict
        ``bag``, exit codes, outputs, the observer's last state, the identification.
    """
    (bridge_exports, bridge_commands), (recording_exports, recording_commands) = \
        [parse_block(b) for b in readme_blocks()]
    long_running = [c for c in recording_commands if c[0] != 'emfc-identify']
    identify_lines = [c for c in recording_commands if c[0] == 'emfc-identify']
    assert len(identify_lines) == 1 and recording_commands[-1] == identify_lines[0]
    started = []
    result = {}

    def start(host, words, env, cwd):
        proc = netns_hosts.HostProcess(host, argv_of(words), logs, env, cwd=cwd)
        started.append((words[0] if words[0] != 'ros2' else words[3], proc))
        return proc

    def outputs():
        return '\n'.join(f'--- {name} ({p.host.name})\n{p.output()[-4000:]}'
                         for name, p in started)

    try:
        for words in bridge_commands:
            proc = start(bridge_host, words, bridge_env, bridge_dir)
            if words[0] == 'emfc-device-emulator':
                # The emulator prints its port once it serves (the first start compiles).
                assert ros_harness.wait_until(
                    lambda: 'listening on' in proc.output() or not proc.alive(),
                    START_TIMEOUT_S), proc.output()
                assert proc.alive(), proc.output()
        observer = Observer(netns_hosts.HostProcess(
            recording_host, [sys.executable, netns_hosts.__file__, 'observe', NAMESPACE],
            logs, recording_env))
        started.append(('observer', observer.process))
        for words in long_running:
            start(recording_host, words, recording_env, recording_dir)

        def finished():
            state = observer.state()
            offset = (state.get('measurements') or {}).get('extra', {}).get(
                'excitation_offset_samples')
            recorder = (state.get('recorder') or {}).get('values', {})
            written = int(recorder.get(f'messages {NAMESPACE}/measurements', 0))
            if (state.get('generator') or {}).get('state') != 'done' or \
                    not isinstance(offset, int):
                return False
            # The recorder's blocks start at device sample 0 (the bridge waited for it).
            return written * 1000 >= offset + total + SETTLE_SAMPLES + 1000

        done = ros_harness.wait_until(
            lambda: finished() or not all(p.alive() for _, p in started), START_TIMEOUT_S,
            poll_s=0.2)
        result['state'] = observer.state()
        assert done and all(p.alive() for _, p in started), \
            f'{json.dumps(result["state"], indent=1)[-3000:]}\n{outputs()}'
        # "Ctrl-C the recorder": it closes the bag; then the rest, each by its pid.
        names = [name for name, _ in started]
        order = ['recorder', 'signal_generator', 'observer', 'daq_bridge',
                 'emfc-device-emulator']
        assert sorted(names) == sorted(order), names
        procs = dict(started)
        result['exits'] = {name: procs[name].stop(STOP_TIMEOUT_S) for name in order}
        result['bag'] = recording_dir / recorder_output(long_running)
        result['outputs'] = outputs()
        if identify:
            proc = netns_hosts.HostProcess(recording_host, argv_of(identify_lines[0]), logs,
                                           recording_env, cwd=recording_dir)
            try:
                result['identify_exit'] = proc.proc.wait(timeout=IDENTIFY_TIMEOUT_S)
            finally:
                proc.stop()
            result['identify_output'] = proc.output()
            # emfc-identify BAG writes <BAG>_identification without -o.
            assert '-o' not in identify_lines[0] and '--out' not in identify_lines[0]
            result['identification'] = recording_dir / f'{identify_lines[0][1]}_identification'
        return result
    finally:
        for _, proc in started:
            proc.stop(STOP_TIMEOUT_S)


def recorder_output(commands):
    """The recorder's ``output:=`` folder from its README line."""
    for words in commands:
        if 'recorder' in words:
            for word in words:
                if word.startswith('output:='):
                    return word.split(':=', 1)[1]
    raise AssertionError('no recorder line with output:= in the README block')


# -- the bag, with the independent mcap reader --------------------------------------------


def mcap_messages(bag, topic):
    out = []
    for path in sorted(Path(bag).glob('*.mcap')):
        with open(path, 'rb') as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            for _, _, _, decoded in reader.iter_decoded_messages(topics=[topic]):
                out.append(decoded)
    return out


def blocks_by_index(bag, topic):
    """
    The recorded blocks of a stream: first sample index to samples (channels x n).

    A block recorded twice (the generator re-sends an unacknowledged window) must be
    identical both times.
    """
    out = {}
    for msg in mcap_messages(bag, topic):
        dims = {d.label: d.size for d in msg.layout.dim}
        offset = msg.layout.data_offset
        header = np.asarray(msg.data[:offset])
        data = np.asarray(msg.data[offset:offset + dims['channel'] * dims['sample']]) \
            .reshape(dims['channel'], dims['sample'])
        first = int(header[0])
        if first in out:
            np.testing.assert_array_equal(out[first], data)
        out[first] = data
    return out


def contiguous(blocks):
    """(first index, samples) of contiguous blocks, or an assertion naming the gap."""
    firsts = sorted(blocks)
    for a, b in zip(firsts, firsts[1:]):
        assert b - a == blocks[a].shape[1], f'gap or overlap after sample {a}'
    return firsts[0], np.concatenate([blocks[f] for f in firsts], axis=1)


def recorded(bag):
    """Measurements (first index, samples, names, offset) and excitation of a bag."""
    descriptions = [json.loads(m.data) for m in
                    mcap_messages(bag, f'{NAMESPACE}/measurements/description')]
    assert descriptions, f'{bag}: no measurement description'
    first, samples = contiguous(blocks_by_index(bag, f'{NAMESPACE}/measurements'))
    exc_first, excitation = contiguous(blocks_by_index(bag, f'{NAMESPACE}/excitation'))
    assert exc_first == 0
    return {'first': first, 'samples': samples,
            'names': [c['name'] for c in descriptions[-1]['channels']],
            'offset': descriptions[-1]['extra']['excitation_offset_samples'],
            'offsets': [d['extra'].get('excitation_offset_samples') for d in descriptions],
            'excitation': excitation}


def off_link(frames, pair, device_port='5555'):
    """
    Captured frame kinds that are not unicast between the two addresses of the link.

    Allowed: ARP, and IPv4 between the two addresses (UDP, its fragments, ICMP port
    unreachable: the answers to Fast DDS probing participant ports nobody uses). Anything else is
    listed: multicast (``SUBNET`` sends discovery to 239.255.0.1), broadcast, IPv6, other
    addresses, and the device protocol's port (it belongs on the bridge computer's
    loopback).
    """
    bad = []
    for kind, (count, _) in frames.items():
        if kind == 'arp':
            continue
        match = re.fullmatch(r'(udp|ip-fragment|icmp 3/3) ([\d.]+)(?::(\d+))? -> '
                             r'([\d.]+)(?::(\d+))?', kind)
        if not match or {match.group(2), match.group(4)} != set(pair) or \
                device_port in (match.group(3), match.group(5)):
            bad.append(f'{kind} ({count} frames)')
    return bad


# -- the runs -----------------------------------------------------------------------------


@pytest.fixture(scope='module')
def runs(tmp_path_factory):
    """The two-computer run (with identification and a capture), then the one-computer run."""
    netns_hosts.require_tools()
    tmp = tmp_path_factory.mktemp('two_hosts')
    logs = tmp / 'logs'
    blocks = [parse_block(b) for b in readme_blocks()]
    (bridge_exports, _), (recording_exports, _) = blocks
    # The link's addresses are the ones each side names as its peer.
    address_bridge = recording_exports['ROS_STATIC_PEERS']
    address_recording = bridge_exports['ROS_STATIC_PEERS']
    for exports in (bridge_exports, recording_exports):
        assert exports['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    experiment_files = [w.split(':=', 1)[1] for _, commands in blocks for c in commands
                        for w in c if w.startswith('experiment_file:=')]
    assert len(experiment_files) == 1
    total = load_experiment_file(SHARE_CONFIG / Path(experiment_files[0]).name).total_samples
    out = {'total': total, 'addresses': (address_bridge, address_recording)}
    hosts = []
    capture = None
    try:
        bridge = netns_hosts.Host('bridge')
        hosts.append(bridge)
        recording = netns_hosts.Host('recording')
        hosts.append(recording)
        netns_hosts.connect(bridge, recording, address_bridge, address_recording, PREFIX,
                            LINK, LINK)
        capture_file = tmp / 'capture.json'
        capture = netns_hosts.HostProcess(
            recording, [sys.executable, netns_hosts.__file__, 'capture', LINK,
                        str(capture_file)], logs, dict(os.environ))
        assert ros_harness.wait_until(lambda: 'ready' in capture.output(), 30.0), \
            capture.output()
        out['before'] = {h.name: h.interfaces() for h in hosts}
        out['two'] = experiment_run(
            bridge, recording, host_environment(bridge_exports),
            host_environment(recording_exports), workdir(tmp / 'bridge'),
            workdir(tmp / 'recording'), logs, total, identify=True)
        out['after'] = {h.name: h.interfaces() for h in hosts}
        assert capture.stop(STOP_TIMEOUT_S) == 0, capture.output()
        out['capture'] = json.loads(capture_file.read_text())
        for host in hosts:
            host.close()
        hosts.clear()
        # One computer: the same lines in one namespace, without ROS_STATIC_PEERS.
        single = netns_hosts.Host('single')
        hosts.append(single)
        out['one'] = experiment_run(
            single, single, host_environment(bridge_exports, drop=['ROS_STATIC_PEERS']),
            host_environment(recording_exports, drop=['ROS_STATIC_PEERS']),
            workdir(tmp / 'single_bridge'), workdir(tmp / 'single_recording'), logs, total,
            identify=False)
        out['one_interfaces'] = single.interfaces()
        yield out
    finally:
        if capture is not None:
            capture.stop(STOP_TIMEOUT_S)
        for host in hosts:
            host.close()


# -- the checks ---------------------------------------------------------------------------


def test_the_options_file_is_the_bridge_plan_s():
    """The README's --options file holds the identification the bridge run plan gives."""
    options = yaml.safe_load((REPO / 'config' / 'identification_bridge_emulator.yaml')
                             .read_text())
    plan = yaml.safe_load((REPO / 'config' / 'experiment_bridge_emulator.yaml').read_text())
    identification = dict(plan['run']['identification'])
    assert identification.pop('enabled') is True
    assert options == identification


@pytest.mark.slow
def test_every_process_ends_cleanly_and_the_bag_is_identified(runs):
    for key in ('two', 'one'):
        run = runs[key]
        assert run['exits'] == dict.fromkeys(run['exits'], 0), (key, run['outputs'])
        state = run['state']
        assert state['generator']['state'] == 'done' and state['generator']['error'] == ''
        assert state['recorder']['level'] == 0, state['recorder']
        assert 'dropped' not in state['recorder']['values'] or \
            state['recorder']['values']['dropped'] == '0', state['recorder']
        bridge = state['daq_bridge']['values']
        for counter in ('published_gaps', 'published_missing_samples',
                        'excitation_late_samples', 'excitation_gap_filled_samples',
                        'reader_errors', 'setpoint_write_errors'):
            assert bridge.get(counter) == '0', (key, counter, bridge)
    two = runs['two']
    assert two['identify_exit'] == 0, two['identify_output'][-4000:]
    results = yaml.safe_load((two['identification'] / 'results.yaml').read_text())
    assert [s['name'] for s in results['sections']] == ['coil_chirp',
                                                        'coil_amplifier_staircase']
    assert results['n_samples'] == runs['total']


@pytest.mark.slow
def test_discovery_and_data_stay_on_the_link_by_unicast(runs):
    address_bridge, address_recording = runs['addresses']
    pair = {address_bridge, address_recording}
    for name, interfaces in runs['after'].items():
        # Each "computer" has loopback and the link, nothing else to send on.
        assert set(interfaces) == {'lo', LINK}, (name, sorted(interfaces))
    assert set(runs['one_interfaces']) == {'lo'}
    capture = runs['capture']
    before, after = runs['before'], runs['after']

    def delta(host, direction, what):
        return (after[host][LINK]['stats64'][direction][what]
                - before[host][LINK]['stats64'][direction][what])

    # The capture saw every frame the link carried while the experiment ran: none dropped,
    # at least as many as the interface counted (it ran from before to after the counts).
    link_frames = delta('recording', 'rx', 'packets') + delta('recording', 'tx', 'packets')
    assert capture['dropped'] == 0, capture['dropped']
    assert capture['frames_total'] >= link_frames > 0, (capture['frames_total'], link_frames)
    assert off_link(capture['frames'], pair) == [], capture['frames']
    # The data crossed the link (kernel counters): the measurements, 6 channels of float64
    # for every recorded sample, from the bridge; the excitation, 2 channels, to it.
    n_measured = recorded(runs['two']['bag'])['samples'].shape[1]
    sent = {host: delta(host, 'tx', 'bytes') for host in after}
    assert delta('bridge', 'tx', 'bytes') == delta('recording', 'rx', 'bytes')
    assert sent['bridge'] > 8 * 6 * n_measured, (sent, n_measured)
    assert sent['recording'] > 8 * 2 * runs['total'], sent
    print(f'link: {sent} bytes sent, {link_frames} frames, {n_measured} samples measured')


@pytest.mark.slow
def test_the_two_computer_bag_equals_the_one_computer_bag_sample_for_sample(runs):
    total = runs['total']
    two, one = recorded(runs['two']['bag']), recorded(runs['one']['bag'])
    assert two['names'] == one['names']
    names = two['names']
    assert {'coil_setpoint_V', 'load_changer_setpoint_V', 'coil_current_A',
            'load_changer_current_A', 'sensor_V', 'position_m'} <= set(names)
    # The excitation, by sample index: the whole experiment in both, equal.
    for bag in (two, one):
        assert bag['excitation'].shape[1] == total
    np.testing.assert_array_equal(two['excitation'], one['excitation'])
    # The measurements from the device's sample 0 (the bridge waited for the recorder).
    assert two['first'] == 0 and one['first'] == 0
    # Lined up on the excitation: device sample offset + k answers excitation sample k.
    before = min(two['offset'], one['offset'])
    after = min(b['samples'].shape[1] - b['offset'] for b in (two, one))
    assert after >= total + SETTLE_SAMPLES
    window = [b['samples'][:, b['offset'] - before:b['offset'] + after] for b in (two, one)]
    for key, bag in (('two computers', two), ('one computer', one)):
        print(f'{key}: excitation offsets in the descriptions {bag["offsets"]}')
    differ = window[0] != window[1]
    if differ.any():
        where = {names[c]: (int(np.flatnonzero(differ[c])[0]) - before,
                            int(np.flatnonzero(differ[c])[-1]) - before, int(differ[c].sum()))
                 for c in range(differ.shape[0]) if differ[c].any()}
        print('differ (first, last excitation sample, count) per channel:', where)
    np.testing.assert_array_equal(window[0], window[1])
    # What makes that comparison meaningful: the excitation crossed the link and was
    # applied (the DAC's setpoint is the experiment's), and the balance answered it.
    coil = window[0][names.index('coil_setpoint_V'), before:before + total]
    np.testing.assert_allclose(coil, two['excitation'][0], atol=DAC_LSB_V)
    position = window[0][names.index('position_m')]
    assert np.all(position[:before] == position[0])         # at rest before the excitation
    assert np.ptp(position[before:before + total]) > 0.0
    print(f'excitation offsets: two computers {two["offset"]}, one computer '
          f'{one["offset"]} device samples; compared {before + after} samples x '
          f'{len(names)} channels')


TALKER = """
import sys, time
import rclpy
from std_msgs.msg import String
rclpy.init()
node = rclpy.create_node(sys.argv[1])
pub = node.create_publisher(String, 'chatter', 10)
heard = []
node.create_subscription(String, 'chatter', lambda m: heard.append(m.data), 10)
deadline = time.monotonic() + 6.0
while time.monotonic() < deadline:
    pub.publish(String(data=sys.argv[1]))
    rclpy.spin_once(node, timeout_sec=0.1)
print(sorted(set(heard)), flush=True)
"""


@pytest.mark.slow
@pytest.mark.parametrize('discovery_range, multicast', [('SUBNET', True), ('LOCALHOST', False)])
def test_the_link_check_sees_subnet_multicast(tmp_path, discovery_range, multicast):
    """The check above can fail: SUBNET with static peers multicasts discovery on the link."""
    netns_hosts.require_tools()
    hosts, procs, capture = [], [], None
    try:
        hosts = [netns_hosts.Host('a'), netns_hosts.Host('b')]
        pair = ('10.231.0.5', '10.231.0.6')
        netns_hosts.connect(hosts[0], hosts[1], *pair, PREFIX, LINK, LINK)
        capture = netns_hosts.HostProcess(
            hosts[1], [sys.executable, netns_hosts.__file__, 'capture', LINK,
                       str(tmp_path / 'capture.json')], tmp_path, dict(os.environ))
        assert ros_harness.wait_until(lambda: 'ready' in capture.output(), 30.0)
        for host, name, peer in ((hosts[0], 'talker_a', pair[1]),
                                 (hosts[1], 'talker_b', pair[0])):
            env = host_environment({'ROS_AUTOMATIC_DISCOVERY_RANGE': discovery_range,
                                    'ROS_STATIC_PEERS': peer})
            procs.append(netns_hosts.HostProcess(host, [sys.executable, '-c', TALKER, name],
                                                 tmp_path, env))
        for proc in procs:
            proc.proc.wait(timeout=scaled(60.0))
        # Either way the two talkers found each other across the link ...
        for proc in procs:
            assert "['talker_a', 'talker_b']" in proc.output(), proc.output()
        assert capture.stop(STOP_TIMEOUT_S) == 0
        frames = json.loads((tmp_path / 'capture.json').read_text())['frames']
        bad = off_link(frames, pair)
        # ... but only SUBNET multicast its discovery.
        assert any('-> 239.255.0.1:' in kind for kind in bad) is multicast, bad
        assert bad if multicast else bad == []
    finally:
        for proc in procs:
            proc.stop()
        if capture is not None:
            capture.stop()
        for host in hosts:
            host.close()
