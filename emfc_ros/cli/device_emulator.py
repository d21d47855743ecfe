"""
emfc-device-emulator: the UDP device emulator (simulated balance inside) as a process.

``emfc-device-emulator [--bind 127.0.0.1] [--port N] [--config balance.yaml] [--channels 6]
[--faults drop=0.01,duplicate=0.01,reorder=0.01,corrupt=0.01,delay_ms=5,stall_s=2,
stall_after_s=1,die_after_s=30,setpoint_drop=0.01] [--seed S] [--duration-s T]
[--key-file device.key] [--allow-remote] [--load-mass-kg KG|balance] [--load-changer-coupled]
[--no-noise] [--control-crossover-Hz 130 [--control-rate-Hz 10000] [--control-notch-Hz 0]]
[--load 0:0,2:0.0734829]``

The simulated balance carries ``--load-mass-kg`` on its pan (``balance``: the mass pieces
that hold the lever at 0 with 0 V on the coil, as ``emfc-experiment`` loads its emulator;
default 0: the empty pan, whose lever rests on its stop at 0 V). ``--no-noise`` leaves out
the sensor and amplifier noise, so that two runs of one excitation give the same samples
wherever the excitation starts on the device clock.

With ``--key-file`` every datagram must be authenticated with that pre-shared key (the
bridge's ``udp.key_file``); an unreadable, group- or world-readable, non-hex or short key
file is refused (exit 2). On exit it prints its counters of refused datagrams (foreign,
unauthenticated, replayed...) to stderr.

Prints the bound UDP port alone on the first line of stdout (``--port 0``, the default,
picks a free one), then serves until SIGINT or SIGTERM, ``--duration-s`` or the injected
death. It refuses a non-loopback ``--bind`` unless ``--allow-remote`` is given. The protocol
is ``docs/device_protocol.md``.

Exit codes: 0 stopped, 3 died as injected (``die_after_s``), 1 the device thread failed,
2 usage or configuration error.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from typing import Any, List, Optional

from emfc_ros.core.control.loop_config import loop_config
from emfc_ros.core.device.auth import load_key_file
from emfc_ros.core.device.emulator import (check_bind_host, DeviceEmulator, Faults,
                                           REFUSED_COUNTERS)
from emfc_ros.core.model.balance_file import load_balance
from emfc_ros.core.weighing.profiles import parse_load_schedule

PROG = 'emfc-device-emulator'


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG, description='Emulate the EMFC balance DAQ/FPGA device over UDP: control '
                               'requests, paced measurement frames, setpoint frames, '
                               'watchdog and fault injection.')
    parser.add_argument('--bind', default='127.0.0.1',
                        help='bind address (default 127.0.0.1; others need --allow-remote)')
    parser.add_argument('--port', type=int, default=0, help='UDP port (default 0: any free)')
    parser.add_argument('--config', help='balance parameters YAML (default: shipped defaults)')
    parser.add_argument('--channels', type=int, default=6,
                        help='analog inputs of the device: most channels a host may select '
                             '(default 6: every channel the identification needs)')
    parser.add_argument('--faults', default='', help='comma-separated key=value faults: drop, '
                        'duplicate, reorder, corrupt (probabilities), delay_ms, stall_s, '
                        'stall_after_s, die_after_s, setpoint_drop (setpoint frames lost on '
                        'their way in)')
    parser.add_argument('--seed', type=int, default=0, help='noise and fault seed')
    parser.add_argument('--duration-s', type=float, default=0.0,
                        help='stop after this long (default 0: run until interrupted)')
    parser.add_argument('--control-crossover-Hz', type=float, default=0.0,
                        help='run the position controller inside the device loop, designed '
                             'for this crossover [Hz] (default 0: open loop)')
    parser.add_argument('--control-rate-Hz', type=float, default=10000.0,
                        help='in-loop controller rate [Hz] (the device rate must be a whole '
                             'multiple)')
    parser.add_argument('--control-notch-Hz', type=float, default=0.0,
                        help='notch of the in-loop controller [Hz] (default 0: none)')
    parser.add_argument('--load-mass-kg', default='0',
                        help="mass on the pan [kg], or 'balance': the mass that holds the "
                             'lever at 0 with 0 V on the coil (default 0: empty pan)')
    parser.add_argument('--load-changer-coupled', action='store_true',
                        help="the load changer's moving mass rides on the pan")
    parser.add_argument('--no-noise', action='store_true',
                        help='no sensor and amplifier noise (deterministic samples)')
    parser.add_argument('--key-file', default='',
                        help='pre-shared key file (hex, mode 600): accept only datagrams '
                             'authenticated with it (HMAC-SHA256), sign every reply and frame')
    parser.add_argument('--load', default='',
                        help="mass on the pan over the device's sample clock: "
                             "'time_s:mass_kg,...' (e.g. 0:0,2:0.0734829), from every start")
    parser.add_argument('--allow-remote', action='store_true',
                        help='permit a non-loopback bind address (exposes the emulator)')
    return parser


def load_mass_kg_argument(text: str, params: Any, coupled: bool) -> float:
    """
    The ``--load-mass-kg`` value of an emulator [kg].

    Parameters
    ----------
    text : str
        A number from 0 to 100, or ``balance`` (the mass that holds the lever at 0 with 0 V
        on the coil).
    params : BalanceParameters
        The balance.
    coupled : bool
        Whether the load changer's moving mass rides on the pan.

    Returns
    -------
    float
        The mass [kg].

    Raises
    ------
    ValueError
        Naming the option and what is allowed.
    """
    if text.strip() == 'balance':
        from emfc_ros.core.sim.balancing import balancing_load_mass_kg
        return balancing_load_mass_kg(params, coupled)
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"--load-mass-kg must be a mass in kg or 'balance', got {text!r}") \
            from None
    if not 0.0 <= value <= 100.0:
        raise ValueError(f'--load-mass-kg must be from 0 to 100 kg, got {text}')
    return value


def main(argv: Optional[List[str]] = None) -> int:
    """
    Run the emulator.

    Parameters
    ----------
    argv : list of str, optional
        Arguments (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit code: 0 stopped, 1 device thread failed, 2 usage or configuration error,
        3 died as injected.
    """
    try:
        args = _parser().parse_args(argv)
    except SystemExit as exc:          # argparse already printed the message
        return int(exc.code or 0)
    try:
        host = check_bind_host(args.bind, args.allow_remote)
        if not 1 <= args.channels <= 64:
            raise ValueError(f'--channels must be in [1, 64], got {args.channels}')
        if not 0 <= args.port <= 65535:
            raise ValueError(f'--port must be in [0, 65535], got {args.port}')
        faults = Faults.parse(args.faults)
        params = load_balance(args.config)
        options = {'load_mass_kg': load_mass_kg_argument(args.load_mass_kg, params,
                                                         args.load_changer_coupled),
                   'load_changer_coupled': bool(args.load_changer_coupled),
                   'noise': not args.no_noise}
        if args.load:
            options['load_schedule'] = parse_load_schedule(args.load)
        if args.control_crossover_Hz > 0.0:
            options['control'] = loop_config({'crossover_Hz': args.control_crossover_Hz,
                                              'rate_Hz': args.control_rate_Hz,
                                              'notch_Hz': args.control_notch_Hz}, '--control')
        key = load_key_file(args.key_file) if args.key_file else None
        emulator = DeviceEmulator(host, args.port, params=params, seed=args.seed,
                                  max_inputs=args.channels, faults=faults,
                                  allow_remote=args.allow_remote, simulator_options=options,
                                  key=key)
        port = emulator.start()
    except (ValueError, OSError) as exc:
        print(f'{PROG}: error: {exc}', file=sys.stderr)
        return 2
    stop = threading.Event()
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: stop.set())
    print(port, flush=True)
    print(f'{PROG}: listening on {host}:{port} (faults: {args.faults or "none"}, '
          f'authentication: {"HMAC-SHA256 key " + args.key_file if key else "none"})',
          file=sys.stderr, flush=True)
    end = time.monotonic() + args.duration_s if args.duration_s > 0 else float('inf')
    try:
        while not stop.is_set() and not emulator.dead.is_set() and time.monotonic() < end:
            stop.wait(min(0.1, max(0.0, end - time.monotonic())))
    except KeyboardInterrupt:
        pass
    died = emulator.dead.is_set()
    emulator.stop()
    counters = emulator.all_counters()
    refused = ', '.join(f'{name} {counters[name]}' for name in REFUSED_COUNTERS
                        if counters.get(name))
    print(f'{PROG}: refused datagrams: {refused or "none"}', file=sys.stderr)
    if emulator.error is not None:
        print(f'{PROG}: device thread failed: {emulator.error!r}', file=sys.stderr)
        return 1
    if died:
        print(f'{PROG}: died as injected', file=sys.stderr)
        return 3
    return 0


if __name__ == '__main__':
    sys.exit(main())
