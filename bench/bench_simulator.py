"""
Simulated samples per second of the plant simulator, against baselines in the same run.

Rows (one core, noise and quantisation on unless stated, 1000-sample blocks as the ROS node
steps it, best of a few repeats, rates normalised to samples per second of wall time):

* ``Simulator`` with the numba kernel (``chain.chain_block`` compiled), ZOH and FOH, and
  without noise or quantisation;
* the same with one big block;
* ``Simulator`` with the interpreted numpy/Python fallback (same math, a shorter input);
* the bare mechanics kernel ``PlantKernel`` (no converters, noise, stops or sensor inverse),
  the reference the design brief quotes, measured round robin with the rows above, and the
  ratio of the full chain to it;
* the same chain with ``scipy.integrate.solve_ivp`` (RK45, rtol 1e-8) doing the mechanics
  sample by sample, DAC, amplifiers, noise, sensor and ADC in numpy (a shorter input).

It prints a table and writes JSON::

    .venv/bin/python bench/bench_simulator.py [--seconds 10] [--repeats 7] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import platform
import sys
import time
from typing import Callable, List, Optional, Tuple

import numpy as np
import scipy
from scipy.integrate import solve_ivp

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))   # the working tree, not an installed copy

from emfc_ros.core.model import (BalanceParameters, lever_position_m,  # noqa: E402
                                 state_derivative)
from emfc_ros.core.sim import (convert_V, numba_available, PlantKernel, Simulator,  # noqa: E402
                               standard_normals)

FS_HZ = 20000.0
BLOCK = 1000


def best_rate(run: Callable[[], int], repeats: int) -> float:
    """Best samples per second of ``run`` (it returns the number of samples) over repeats."""
    best = 0.0
    for _ in range(repeats):
        start = time.perf_counter()
        n = run()
        best = max(best, n / (time.perf_counter() - start))
    return best


def cpu_ticks() -> Optional[Tuple[int, int]]:
    """
    Steal and total CPU ticks of the machine from ``/proc/stat`` (None where there is none).

    Steal is time the hypervisor gave this VM's virtual CPUs to someone else: a slow spell
    with steal is the host's, not the code's.
    """
    try:
        with open('/proc/stat', encoding='ascii') as stream:
            fields = [int(v) for v in stream.readline().split()[1:]]
    except (OSError, ValueError):
        return None
    return (fields[7] if len(fields) > 7 else 0), sum(fields)


def excitation(params: BalanceParameters, n: int) -> np.ndarray:
    """Hold setpoints plus a small coil sine and load-changer steps, shape (2, n)."""
    hold = Simulator(params, FS_HZ, noise=False).hold_setpoints_V
    k = np.arange(n)
    u = np.tile(hold[:, None], (1, n))
    u[0] += 2e-3 * np.sin(2.0 * np.pi * 37.0 * k / FS_HZ)
    u[1] += 0.05 * ((k // 5000) % 2)
    return u


def simulator_run(params: BalanceParameters, u: np.ndarray, block: int,
                  **kwargs) -> Callable[[], int]:
    sim = Simulator(params, FS_HZ, 1, **kwargs)
    sim.step_block(u[:, :10])        # compile (or load from the cache) outside the timing

    def run() -> int:
        sim.reset()
        for first in range(0, u.shape[1], block):
            sim.step_block(u[:, first:first + block])
        return u.shape[1]
    return run


def bare_run(params: BalanceParameters, u: np.ndarray, block: int,
             backend: str) -> Callable[[], int]:
    kernel = PlantKernel(params, FS_HZ, backend=backend)
    kernel.run(u[0, :10], u[1, :10])

    def run() -> int:
        for first in range(0, u.shape[1], block):
            kernel.run(u[0, first:first + block], u[1, first:first + block])
        return u.shape[1]
    return run


def solve_ivp_run(params: BalanceParameters, u: np.ndarray) -> Callable[[], int]:
    """The chain with solve_ivp per sample for the mechanics (ZOH), the rest in numpy."""
    conv = params.converters
    start = Simulator(params, FS_HZ, noise=False)
    mech = start.mechanics
    dt = 1.0 / FS_HZ

    def run() -> int:
        n = u.shape[1]
        z = standard_normals(1, 0, n)
        v = convert_V(u, conv.dac_bits, conv.dac_range_V)
        i_c = np.clip(params.coil_amplifier.current_A(v[0]) + z[1] * conv.coil_current_noise_A_rms,
                      -conv.coil_current_limit_A, conv.coil_current_limit_A)
        i_l = np.clip(params.load_changer_amplifier.current_A(v[1])
                      + z[2] * conv.load_changer_current_noise_A_rms,
                      -conv.load_changer_current_limit_A, conv.load_changer_current_limit_A)
        f_p = params.load_changer.force_N(i_l)
        x = start.state
        y = np.empty(n)
        for i in range(n):
            y[i] = lever_position_m(x, mech)

            def rhs(t, xx, ic=i_c[i], fp=f_p[i]):
                return state_derivative(xx, params.motor.force_N(ic, lever_position_m(xx, mech)),
                                        fp, mech)
            x = solve_ivp(rhs, (0.0, dt), x, method='RK45', rtol=1e-8, atol=1e-15).y[:, -1]
        y_meas = np.clip(y + z[0] * conv.sensor_noise_m_rms, -conv.sensor_range_m,
                         conv.sensor_range_m)
        sensor = convert_V(params.sensor.voltage_V(y_meas), conv.adc_bits, conv.adc_range_V)
        params.sensor.position_m(sensor)
        convert_V(100.0 * i_c, conv.adc_bits, conv.adc_range_V)
        return n
    return run


def main(argv: List[str] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seconds', type=float, default=10.0,
                        help='simulated seconds for the compiled rows (default 10 s at 20 kHz)')
    parser.add_argument('--repeats', type=int, default=7)
    parser.add_argument('--json', type=Path, default=ROOT / 'bench' / 'results' /
                        'simulator.json')
    args = parser.parse_args(argv)
    params = BalanceParameters()
    n_fast = int(args.seconds * FS_HZ)
    u = excitation(params, n_fast)
    rows = []

    def add(name: str, rate: float, samples: int, note: str) -> None:
        rows.append({'name': name, 'samples_per_s': rate, 'real_time_factor_at_20kHz':
                     rate / FS_HZ, 'samples': samples, 'note': note})
        print(f'{name:44s} {rate / 1e6:9.3f} M/s  {rate / FS_HZ:9.1f} x real time  '
              f'({samples} samples) {note}', flush=True)

    print(f'{platform.processor() or platform.machine()}, python {platform.python_version()}, '
          f'numpy {np.__version__}, scipy {scipy.__version__}, numba available: '
          f'{numba_available()}; {FS_HZ:g} Hz, blocks of {BLOCK}')
    fast = []
    if numba_available():
        fast = [
            ('simulator numba (noise+quant, zoh)', simulator_run(params, u, BLOCK),
             'full chain'),
            ('simulator numba (noise+quant, foh)', simulator_run(params, u, BLOCK, hold='foh'),
             ''),
            ('simulator numba (noise+quant, one block)', simulator_run(params, u, n_fast), ''),
            ('simulator numba (no noise, no quant)',
             simulator_run(params, u, BLOCK, noise=False, quantisation=False), ''),
            ('bare mechanics PlantKernel numba', bare_run(params, u, BLOCK, 'numba'),
             'reference: RK4 of the mechanics only'),
        ]
    # round robin over the repeats, so that a busy spell of the machine hits every row alike
    best = [0.0] * len(fast)
    ticks0 = cpu_ticks()
    for _ in range(args.repeats):
        for i, (_, run, _) in enumerate(fast):
            best[i] = max(best[i], best_rate(run, 1))
    ticks1 = cpu_ticks()
    steal = None
    if ticks0 and ticks1 and ticks1[1] > ticks0[1]:
        steal = (ticks1[0] - ticks0[0]) / (ticks1[1] - ticks0[1])
        print(f'CPU time stolen by the hypervisor during the compiled rows: {100 * steal:.1f} % '
              f'of the CPU time of all CPUs (/proc/stat)')
    for (name, _, note), rate in zip(fast, best):
        add(name, rate, n_fast, note)
    n_slow = 2000
    add('simulator numpy fallback (noise+quant)',
        best_rate(simulator_run(params, u[:, :n_slow], BLOCK, backend='numpy'), 1), n_slow,
        'interpreted, same math')
    add('bare mechanics PlantKernel numpy',
        best_rate(bare_run(params, u[:, :n_slow], BLOCK, 'numpy'), 1), n_slow, '')
    n_ivp = 400
    add('solve_ivp per sample (RK45 rtol 1e-8) + numpy',
        best_rate(solve_ivp_run(params, u[:, :n_ivp]), 1), n_ivp, 'baseline')
    base = {r['name']: r['samples_per_s'] for r in rows}
    full = base.get('simulator numba (noise+quant, zoh)')
    if full:
        for r in rows:
            r['relative_to_full_chain_numba'] = r['samples_per_s'] / full
        bare = base['bare mechanics PlantKernel numba']
        print(f'full chain (noise+quant, zoh) / bare mechanics, same run: {full / bare:.2f}; '
              f'target 10 M/s: {"met" if full >= 1e7 else "not met"}')
    args.json.parent.mkdir(parents=True, exist_ok=True)
    with open(args.json, 'w', encoding='utf-8') as stream:
        json.dump({'sample_rate_Hz': FS_HZ, 'block_samples': BLOCK,
                   'machine': platform.machine(), 'python': platform.python_version(),
                   'numpy': np.__version__, 'scipy': scipy.__version__,
                   'steal_fraction': steal, 'rows': rows}, stream,
                  indent=2)
        stream.write('\n')
    print(f'wrote {args.json}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
