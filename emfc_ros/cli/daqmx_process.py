"""``emfc-daqmx-emulator`` as a child process of a command (the runner's ``start_emulator``)."""

from __future__ import annotations

from pathlib import Path
import selectors
import signal
import subprocess
import sys
import time
from typing import List, Optional, Tuple

#: Longest wait for the emulator to print its port [s] (it compiles nothing; imports only).
START_TIMEOUT_S = 60.0


class DaqmxEmulatorProcess:
    """
    The emulated NI-DAQmx device in a process of its own, on loopback, ended by its pid.

    Parameters
    ----------
    host : str
        Loopback address to serve on.
    port : int
        gRPC port (0: any free one).
    seed : int
        Noise seed.
    load_mass_kg : float
        Mass on the pan [kg].
    load_changer_coupled : bool
        The load changer's moving mass rides on the pan.
    noise : bool
        Sensor and amplifier noise.
    balance_file : Path, optional
        The balance parameters (the shipped default when None).

    Raises
    ------
    RuntimeError
        If it does not start (its error output in the message).
    """

    what = 'emulated NI-DAQmx device (emfc-daqmx-emulator, its own process)'

    def __init__(self, host: str = '127.0.0.1', port: int = 0, *, seed: int = 0,
                 load_mass_kg: float = 0.0, load_changer_coupled: bool = False,
                 noise: bool = True, balance_file: Optional[Path] = None) -> None:
        args: List[str] = [sys.executable, '-m', 'emfc_ros.cli.daqmx_emulator',
                           '--listen', f'{host}:{int(port)}', '--seed', str(int(seed)),
                           '--load-mass-kg', repr(float(load_mass_kg))]
        if load_changer_coupled:
            args.append('--load-changer-coupled')
        if not noise:
            args.append('--no-noise')
        if balance_file is not None:
            args += ['--config', str(balance_file)]
        self.proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True)
        line = self._first_line(START_TIMEOUT_S)
        if not line.strip().isdigit():
            self.stop()
            err = self.proc.stderr.read() if self.proc.stderr else ''
            raise RuntimeError(f'cannot start emfc-daqmx-emulator: {err.strip() or line}')
        self.host = host
        self.port = int(line)

    def _first_line(self, timeout_s: float) -> str:
        sel = selectors.DefaultSelector()
        sel.register(self.proc.stdout, selectors.EVENT_READ)
        try:
            end = time.monotonic() + timeout_s
            while time.monotonic() < end:
                if sel.select(timeout=0.1):
                    return self.proc.stdout.readline()
                if self.proc.poll() is not None:
                    return ''
            return ''
        finally:
            sel.close()

    @property
    def address(self) -> Tuple[str, int]:
        """The ``(host, port)`` served."""
        return self.host, self.port

    def stop(self, timeout_s: float = 10.0) -> Optional[int]:
        """
        End the process (SIGTERM, then SIGKILL after ``timeout_s``).

        Returns
        -------
        int or None
            Its exit code.
        """
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5.0)
        for stream in (self.proc.stdout, self.proc.stderr):
            if stream is not None:
                stream.close()
        return self.proc.returncode
