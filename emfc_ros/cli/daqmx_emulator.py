"""
emfc-daqmx-emulator: an emulated NI-DAQmx device behind an NI gRPC Device Server interface.

``emfc-daqmx-emulator [--listen 127.0.0.1:0] [--device Dev1] [--config balance.yaml]
[--seed S] [--load-mass-kg KG|balance] [--load-changer-coupled] [--no-noise]
[--remove-after-s T] [--duration-s T] [--watchdog ao|dio-pfi] [--allow-remote]``

One X Series-like device (``ai0:7``, ``ao0:1``, the terminals ``/Dev1/ai/SampleClock`` and
``/Dev1/ai/StartTrigger``, a watchdog timer) with the simulated balance wired to its
terminals as ``docs/daqmx.md`` shows. NI's own client reaches it with
``nidaqmx.Task(grpc_options=nidaqmx.GrpcSessionOptions(grpc.insecure_channel(address),
session_name))``; the ``daqmx`` back-end with ``daqmx.grpc_address``. Calls the emulation does
not implement answer NI-DAQmx error -209876 (function not supported by the device).

Prints the bound port alone on the first line of stdout (port 0, the default, picks a free
one), then serves until SIGINT or SIGTERM or ``--duration-s``. ``--remove-after-s`` removes
the device that long after start (every later call fails with NI-DAQmx error -200045, device
removed), the emulated counterpart of a cable pulled out. ``--watchdog`` says what the
device's watchdog timer covers: ``ao`` (the default) takes analog-output expiration states,
as a CompactDAQ chassis with analog-output modules does; ``dio-pfi`` covers digital lines
only, as an X Series device's does, and refuses AO expiration states with NI-DAQmx error
-200197 (the back-end then runs without a hardware watchdog and says so). It refuses a
non-loopback ``--listen`` host unless ``--allow-remote`` is given.

Exit codes: 0 stopped, 1 the device failed, 2 usage or configuration error.
"""

from __future__ import annotations

import argparse
import gc
import signal
import sys
import threading
import time
from typing import List, Optional, Tuple

from emfc_ros.cli.device_emulator import load_mass_kg_argument
from emfc_ros.core.device.daqmx_wiring import DEFAULT_DEVICE
from emfc_ros.core.device.emulator import check_bind_host
from emfc_ros.core.model.balance_file import load_balance

PROG = 'emfc-daqmx-emulator'


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG, description='Emulate an NI-DAQmx device (X Series-like, simulated EMFC '
                               'balance on its terminals) as an NI gRPC Device Server.')
    parser.add_argument('--listen', default='127.0.0.1:0',
                        help='host:port to serve on (default 127.0.0.1:0, a free port; other '
                             'hosts need --allow-remote)')
    parser.add_argument('--device', default=DEFAULT_DEVICE, help='device name (default Dev1)')
    parser.add_argument('--config', help='balance parameters YAML (default: shipped defaults)')
    parser.add_argument('--seed', type=int, default=0, help='noise seed')
    parser.add_argument('--load-mass-kg', default='0',
                        help="mass on the pan [kg], or 'balance': the mass that holds the "
                             'lever at 0 with 0 V on the coil')
    parser.add_argument('--load-changer-coupled', action='store_true',
                        help="the load changer's moving mass rides on the pan")
    parser.add_argument('--no-noise', action='store_true',
                        help='no sensor and amplifier noise')
    parser.add_argument('--remove-after-s', type=float, default=0.0,
                        help='remove the device this long after start [s] (0: never)')
    parser.add_argument('--duration-s', type=float, default=0.0,
                        help='serve this long, then exit 0 [s] (0: until a signal)')
    parser.add_argument('--watchdog', choices=('ao', 'dio-pfi'), default='ao',
                        help="what the watchdog timer covers: 'ao' analog outputs (as a "
                             "CompactDAQ chassis; default), 'dio-pfi' digital lines only (as "
                             'an X Series device: AO expiration states refused)')
    parser.add_argument('--allow-remote', action='store_true',
                        help='allow a non-loopback --listen host')
    return parser


def parse_listen(text: str, allow_remote: bool = False) -> Tuple[str, int]:
    """
    ``host:port`` to its parts, the host checked for loopback.

    Parameters
    ----------
    text : str
        ``'127.0.0.1:50051'`` (an IPv6 host in brackets: ``'[::1]:0'``).
    allow_remote : bool
        Accept a non-loopback host.

    Returns
    -------
    (str, int)
        Host and port.

    Raises
    ------
    ValueError
        If malformed, the port is out of range, or the host is not loopback.
    """
    host, sep, port = text.rpartition(':')
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ValueError(f'--listen must be host:port with a port in [0, 65535], got {text!r}')
    host = host.strip('[]')
    check_bind_host(host, allow_remote)
    return host, int(port)


def main(argv: Optional[List[str]] = None) -> int:
    """
    Run the emulated device until a signal or ``--duration-s``.

    Parameters
    ----------
    argv : list of str, optional
        Arguments (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit code: 0 stopped, 1 the device failed, 2 usage or configuration error.
    """
    try:
        args = _parser().parse_args(argv)
    except SystemExit as exc:          # argparse already printed the message
        return int(exc.code or 0)
    try:
        host, port = parse_listen(args.listen, args.allow_remote)
        from emfc_ros.core.device.daqmx_emulator.model import Device
        from emfc_ros.core.device.daqmx_emulator.plant import BalancePlant
        from emfc_ros.core.device.daqmx_emulator.server import DaqmxServicer, serve
        params = load_balance(args.config)
        options = {'load_mass_kg': load_mass_kg_argument(args.load_mass_kg, params,
                                                         args.load_changer_coupled),
                   'load_changer_coupled': bool(args.load_changer_coupled),
                   'noise': not args.no_noise}
        plant = BalancePlant(params, args.seed, simulator_options=options)
        device = Device(plant, args.device, clock=time.monotonic,
                        ao_watchdog=args.watchdog == 'ao')
        servicer = DaqmxServicer(device)
        address = f'[{host}]:{port}' if ':' in host else f'{host}:{port}'
        server, bound = serve(servicer, address)
        # what exists now lives as long as the process: out of the collector's way, so that
        # a full collection does not stall the sample clock's thread for tens of ms
        gc.freeze()
    except ImportError as exc:
        print(f'{PROG}: error: the NI-DAQmx client is not installed ({exc}); install the '
              "extra: pip install 'emfc_ros[daqmx]'", file=sys.stderr)
        return 2
    except (ValueError, OSError) as exc:
        print(f'{PROG}: error: {exc}', file=sys.stderr)
        return 2
    stop = threading.Event()
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: stop.set())
    print(bound, flush=True)
    print(f'{PROG}: device {args.device} served on {host}:{bound}', file=sys.stderr,
          flush=True)
    start = time.monotonic()
    end = start + args.duration_s if args.duration_s > 0 else float('inf')
    removed = False
    try:
        while not stop.is_set() and time.monotonic() < end and servicer.pump_error is None:
            if args.remove_after_s > 0 and not removed and \
                    time.monotonic() - start >= args.remove_after_s:
                with servicer.lock:
                    device.remove()
                removed = True
                print(f'{PROG}: device {args.device} removed as asked', file=sys.stderr,
                      flush=True)
            stop.wait(0.05)
    except KeyboardInterrupt:
        pass
    servicer.close()
    server.stop(1.0).wait(2.0)
    if servicer.pump_error is not None:
        print(f'{PROG}: the device failed: {servicer.pump_error!r}', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
