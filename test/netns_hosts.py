"""
Two (or more) "computers" on this machine: network namespaces joined by a veth pair.

Each :class:`Host` is a network namespace plus a mount namespace with its own ``/dev/shm``
(so that Fast DDS cannot take its shared-memory shortcut between the hosts: their data have
to cross the link, as between two computers), held open by one process of ours. Commands run
in it through ``nsenter``; :func:`connect` joins two hosts with a veth pair created inside
the first host, so that nothing is ever added to the test's own namespace or the machine's.
Every host has only ``lo`` and its end of the link; the addresses are private ones of the
test's choosing and never leave these namespaces.

``python netns_hosts.py capture IFACE OUT.json`` (run inside a host) counts every frame on an
interface by kind, addresses and ports until SIGINT/SIGTERM and writes the counts as JSON;
``python netns_hosts.py observe`` (inside a host) prints, as JSON lines, what the test needs
to know of a running experiment (generator status, measurement description, recorder and
bridge diagnostics).

Needs root (namespaces, mounts, links) and iproute2's ``ip``, util-linux's ``unshare`` and
``nsenter``: :func:`require_tools` says clearly what is missing.
"""

from __future__ import annotations

import ipaddress
import json
import os
from pathlib import Path
import select
import shutil
import signal
import socket
import struct
import subprocess
import sys
import time
from typing import Dict, List, Optional, Sequence

import ros_harness
from ros_harness import scaled

TOOLS = ('ip', 'unshare', 'nsenter')
#: Bound on any one namespace or link command [s].
COMMAND_TIMEOUT_S = scaled(30.0)


class HostSetupError(RuntimeError):
    """A namespace, mount or link could not be set up (not root, a tool missing, refused)."""


def require_tools() -> None:
    """
    Check that this process can make hosts: root, ``ip``, ``unshare``, ``nsenter``.

    Raises
    ------
    HostSetupError
        Naming what is missing and how to get it.
    """
    if os.geteuid() != 0:
        raise HostSetupError('the two-host test needs root (network and mount namespaces, '
                             'veth links); run it as root, as CI does: ./tools/test.sh')
    missing = [t for t in TOOLS if shutil.which(t) is None]
    if missing:
        raise HostSetupError(f'missing {missing}: install iproute2 (ip) and util-linux '
                             '(unshare, nsenter); ./tools/setup_env.sh installs iproute2 when '
                             'root')


def _run(argv: Sequence[str], what: str) -> str:
    try:
        done = subprocess.run(list(argv), capture_output=True, text=True,
                              timeout=COMMAND_TIMEOUT_S, check=False)
    except subprocess.TimeoutExpired:
        raise HostSetupError(f'{what}: `{" ".join(argv)}` did not finish in '
                             f'{COMMAND_TIMEOUT_S} s') from None
    if done.returncode != 0:
        raise HostSetupError(f'{what}: `{" ".join(argv)}` failed ({done.returncode}): '
                             f'{done.stderr.strip() or done.stdout.strip()}')
    return done.stdout


class Host:
    """
    A network namespace with only ``lo`` (up) and a private ``/dev/shm``.

    Parameters
    ----------
    name : str
        For messages.
    shm_size_B : int
        Size bound of the host's ``/dev/shm`` tmpfs [bytes].

    Raises
    ------
    HostSetupError
        If the namespaces cannot be made.
    """

    def __init__(self, name: str, shm_size_B: int = 512 << 20) -> None:
        self.name = name
        # The holder: new network and mount namespaces (mounts private), its own /dev/shm,
        # lo up; then it waits on its stdin, so it ends when we close that pipe or die.
        script = (f'mount -t tmpfs -o size={int(shm_size_B)},mode=1777 emfc-{name}-shm '
                  '/dev/shm && ip link set lo up && echo ready && exec cat >/dev/null')
        self._holder = subprocess.Popen(
            ['unshare', '--net', '--mount', '--propagation', 'private', '--', 'sh', '-c',
             script], stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            text=True)
        self.pid = self._holder.pid
        ready, _, _ = select.select([self._holder.stdout], [], [], COMMAND_TIMEOUT_S)
        line = self._holder.stdout.readline() if ready else ''
        if line.strip() != 'ready':
            if self._holder.poll() is None:
                os.kill(self.pid, signal.SIGKILL)
                self._holder.wait(timeout=COMMAND_TIMEOUT_S)
            err = self._holder.stderr.read()
            self.close()
            raise HostSetupError(f'host {name}: could not make its namespaces (unshare '
                                 f'--net --mount, tmpfs on /dev/shm, lo up): {err.strip()}')

    def command(self, argv: Sequence[str], cwd: Optional[Path] = None) -> List[str]:
        """
        The command line that runs ``argv`` inside this host.

        Parameters
        ----------
        argv : sequence of str
            The command.
        cwd : pathlib.Path, optional
            Its working directory (entering a mount namespace starts at ``/``).

        Returns
        -------
        list of str
            ``nsenter -t <pid> --net --mount [--wd=cwd] -- argv`` (no fork: its pid is the
            command's).
        """
        wd = [f'--wd={Path(cwd).resolve()}'] if cwd is not None else []
        return ['nsenter', '-t', str(self.pid), '--net', '--mount'] + wd + ['--'] + list(argv)

    def run(self, argv: Sequence[str], what: str = '') -> str:
        """
        Run a short command inside the host and return its stdout.

        Parameters
        ----------
        argv : sequence of str
            The command.
        what : str
            For the error message.

        Returns
        -------
        str
            Its standard output.

        Raises
        ------
        HostSetupError
            If it fails or takes longer than :data:`COMMAND_TIMEOUT_S`.
        """
        return _run(self.command(argv), what or f'host {self.name}')

    def interfaces(self) -> Dict[str, dict]:
        """
        The host's interfaces with their counters (``ip -s -j link``).

        Returns
        -------
        dict
            Interface name to its ``ip -j`` record (``stats64``: ``rx``/``tx`` ``bytes``,
            ``packets``, ``multicast``...).
        """
        return {link['ifname']: link
                for link in json.loads(self.run(['ip', '-s', '-j', 'link', 'show']))}

    def close(self, timeout_s: float = scaled(10.0)) -> None:
        """End the holder (by its pid); the namespaces go with the last process in them."""
        if self._holder.poll() is None:
            try:
                self._holder.stdin.close()
            except OSError:
                pass
            try:
                self._holder.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                os.kill(self.pid, signal.SIGKILL)
                self._holder.wait(timeout=timeout_s)
        for stream in (self._holder.stdin, self._holder.stdout, self._holder.stderr):
            if stream is not None and not stream.closed:
                stream.close()


def connect(a: Host, b: Host, address_a: str, address_b: str, prefix: int = 30,
            name_a: str = 'emfc0', name_b: str = 'emfc0') -> None:
    """
    Join two hosts with a veth pair and give each end its address.

    The pair is created inside host ``a`` with its peer moved to host ``b`` at once; IPv6
    link-local addresses are not generated (``addrgenmode none``), so the link carries only
    what the processes send (and ARP). Returns once both ends are up.

    Parameters
    ----------
    a, b : Host
        The hosts.
    address_a, address_b : str
        IPv4 addresses of the two ends.
    prefix : int
        Prefix length of the link's subnet.
    name_a, name_b : str
        Interface names in ``a`` and ``b``.

    Raises
    ------
    HostSetupError
        If a step fails.
    """
    net = ipaddress.ip_network(f'{address_a}/{prefix}', strict=False)
    if ipaddress.ip_address(address_b) not in net or not net.is_private:
        raise HostSetupError(f'{address_a} and {address_b} must share a private /{prefix}')
    a.run(['ip', 'link', 'add', name_a, 'type', 'veth', 'peer', 'name', name_b, 'netns',
           str(b.pid)], 'veth pair')
    for host, name, address in ((a, name_a, address_a), (b, name_b, address_b)):
        host.run(['ip', 'link', 'set', 'dev', name, 'addrgenmode', 'none'], 'no IPv6 address')
        host.run(['ip', 'addr', 'add', f'{address}/{prefix}', 'dev', name], 'address')
        host.run(['ip', 'link', 'set', 'dev', name, 'up'], 'link up')
    # Wait until both ends carry traffic: a DDS participant created before that finds no
    # usable interface, announces 127.0.0.1 only and can never be reached over the link.
    deadline = time.monotonic() + COMMAND_TIMEOUT_S
    while not all(host.interfaces()[name]['operstate'] == 'UP'
                  for host, name in ((a, name_a), (b, name_b))):
        if time.monotonic() > deadline:
            raise HostSetupError(f'the link {name_a}-{name_b} did not come up in '
                                 f'{COMMAND_TIMEOUT_S} s')
        time.sleep(0.05)


class HostProcess(ros_harness.NodeProcess):
    """
    A command running inside a host, with exactly the environment given, stopped by its pid.

    Unlike :class:`ros_harness.NodeProcess` the discovery variables are not forced to
    loopback: inside these namespaces the only way out is the veth link the test made.

    Parameters
    ----------
    host : Host
        Where it runs.
    argv : sequence of str
        The command.
    log_dir : pathlib.Path
        Where stdout and stderr are written.
    env : dict
        The complete environment.
    cwd : pathlib.Path, optional
        Working directory.
    """

    def __init__(self, host: Host, argv: Sequence[str], log_dir: Path, env: Dict[str, str],
                 cwd: Optional[Path] = None) -> None:
        log_dir.mkdir(parents=True, exist_ok=True)
        self.host = host
        self.argv = list(argv)
        self.stdout_path = log_dir / f'{host.name}.{Path(argv[0]).name}.{time.monotonic_ns()}.out'
        self.stdout = open(self.stdout_path, 'wb')
        self.proc = subprocess.Popen(host.command(self.argv, cwd), stdout=self.stdout,
                                     stderr=subprocess.STDOUT, env=dict(env))
        self.pid = self.proc.pid
        self.killed = False


# -- run inside a host: frame capture and experiment observer -----------------------------

ETH_P_ALL = 0x0003
ETH_P_IP = 0x0800
ETH_P_ARP = 0x0806
ETH_P_IPV6 = 0x86DD
SO_RCVBUFFORCE = 33            # <asm-generic/socket.h>
SOL_PACKET = 263               # <linux/socket.h>
PACKET_STATISTICS = 6          # <linux/if_packet.h>


def classify(frame: bytes) -> str:
    """
    One frame as ``kind src -> dst`` (IPv4 UDP/TCP with ports, ICMP, ARP, IPv6, other).

    Parameters
    ----------
    frame : bytes
        An Ethernet frame.

    Returns
    -------
    str
        For example ``'udp 10.231.0.2:7413 -> 10.231.0.1:7410'``, ``'arp'``,
        ``'ipv6 -> ff02::16'``, ``'ip-fragment 10.231.0.1 -> 10.231.0.2'``, ``'icmp 3/3
        10.231.0.1 -> 10.231.0.2'`` (type/code: port unreachable).
    """
    if len(frame) < 14:
        return 'short'
    eth_type = struct.unpack('!H', frame[12:14])[0]
    payload = frame[14:]
    if eth_type == ETH_P_ARP:
        return 'arp'
    if eth_type == ETH_P_IPV6:
        dst = socket.inet_ntop(socket.AF_INET6, payload[24:40]) if len(payload) >= 40 else '?'
        return f'ipv6 -> {dst}'
    if eth_type != ETH_P_IP or len(payload) < 20:
        return f'ethertype {eth_type:#06x}'
    ihl = (payload[0] & 0x0F) * 4
    proto = payload[9]
    src = socket.inet_ntoa(payload[12:16])
    dst = socket.inet_ntoa(payload[16:20])
    fragment_offset = struct.unpack('!H', payload[6:8])[0] & 0x1FFF
    if fragment_offset:
        return f'ip-fragment {src} -> {dst}'
    if proto in (6, 17) and len(payload) >= ihl + 4:
        sport, dport = struct.unpack('!HH', payload[ihl:ihl + 4])
        return f'{"udp" if proto == 17 else "tcp"} {src}:{sport} -> {dst}:{dport}'
    if proto == 1 and len(payload) >= ihl + 2:
        return f'icmp {payload[ihl]}/{payload[ihl + 1]} {src} -> {dst}'
    return f'ip-proto-{proto} {src} -> {dst}'


def capture(interface: str, out: Path, max_s: float = 900.0) -> int:
    """
    Count every frame on ``interface`` (both directions) until SIGINT/SIGTERM or ``max_s``.

    Prints ``ready`` once the socket is bound; when it stops, writes ``{"frames": {kind:
    [count, bytes]}, "frames_total": n, "dropped": d}`` to ``out`` (JSON), ``dropped``
    being the frames the kernel could not queue for the socket (its ``PACKET_STATISTICS``).

    Parameters
    ----------
    interface : str
        The interface.
    out : pathlib.Path
        The JSON file.
    max_s : float
        Bound on the capture [s].

    Returns
    -------
    int
        0.
    """
    stop = {'now': False}

    def _stop(*_):
        stop['now'] = True

    signal.signal(signal.SIGINT, _stop)
    signal.signal(signal.SIGTERM, _stop)
    sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
    sock.bind((interface, 0))
    # Root may exceed net.core.rmem_max: 32 MB hold about 20 s of the link's traffic.
    sock.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, 32 << 20)
    sock.settimeout(0.1)
    counts: Dict[str, List[int]] = {}
    print('ready', flush=True)
    deadline = time.monotonic() + max_s
    while not stop['now'] and time.monotonic() < deadline:
        try:
            frame = sock.recv(65535)
        except socket.timeout:
            continue
        except InterruptedError:
            continue
        entry = counts.setdefault(classify(frame), [0, 0])
        entry[0] += 1
        entry[1] += len(frame)
    # tp_packets, tp_drops: what the kernel queued for this socket and what it dropped.
    received, dropped = struct.unpack('II', sock.getsockopt(SOL_PACKET, PACKET_STATISTICS, 8))
    sock.close()
    out.write_text(json.dumps({'frames': counts, 'dropped': dropped,
                               'frames_total': sum(c for c, _ in counts.values())},
                              indent=1, sort_keys=True))
    return 0


def observe(namespace: str = '/emfc', max_s: float = 900.0) -> int:
    """
    Print what a running experiment shows, as JSON lines, until SIGINT or ``max_s``.

    Subscribes (never to the block streams, so that no publisher waiting for a subscriber
    counts it) to the signal generator's status, the measurement description and
    ``/diagnostics``; prints a line whenever one of them changes.

    Parameters
    ----------
    namespace : str
        The suite's namespace.
    max_s : float
        Bound on the observation [s].

    Returns
    -------
    int
        0.
    """
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from std_msgs.msg import String
    from diagnostic_msgs.msg import DiagnosticArray

    from emfc_ros.nodes.convert import LATCHED_QOS, msg_to_description

    rclpy.init()
    node = rclpy.create_node('two_hosts_observer', namespace=namespace)
    seen: Dict[str, object] = {}

    def emit(key: str, value: object) -> None:
        if seen.get(key) != value:
            seen[key] = value
            print(json.dumps({key: value, 't': time.monotonic()}), flush=True)

    def on_description(msg: String) -> None:
        description = msg_to_description(msg)
        emit('measurements', {'channels': list(description.channel_names),
                              'extra': {k: v for k, v in description.extra.items()
                                        if isinstance(v, (str, int, float, bool))}})

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            name = status.name.split(':')[0].strip().rsplit('/', 1)[-1]
            emit(name, {'level': int.from_bytes(status.level, 'little')
                        if isinstance(status.level, bytes) else int(status.level),
                        'message': status.message,
                        'values': {kv.key: kv.value for kv in status.values}})

    node.create_subscription(String, 'signal_generator/status',
                             lambda m: emit('generator', json.loads(m.data)), LATCHED_QOS)
    node.create_subscription(String, 'measurements/description', on_description,
                             LATCHED_QOS)
    node.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 100)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    deadline = time.monotonic() + max_s
    try:
        while rclpy.ok() and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.remove_node(node)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def _main(argv: Sequence[str]) -> int:
    if len(argv) == 3 and argv[0] == 'capture':
        return capture(argv[1], Path(argv[2]))
    if len(argv) in (1, 2) and argv[0] == 'observe':
        return observe(*argv[1:])
    print('usage: netns_hosts.py capture IFACE OUT.json | observe [NAMESPACE]',
          file=sys.stderr)
    return 2


if __name__ == '__main__':
    sys.exit(_main(sys.argv[1:]))
