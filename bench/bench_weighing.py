"""
Weighing on the simulated closed loop: time to a reading within 1 mg and 0.1 mg, and CPU cost.

One run, same simulated data for every estimator (issue 7, benchmark):

* the balance in closed loop (``ClosedLoopSimulator``: PID + lead + notch at 10 kHz, 1.5
  samples of delay, simulator at 20 kHz, noise and quantisation on), zeroed with the empty
  pan and adjusted with a 100 g reference weight, then load steps of the masses below;
* after each step, the time until the estimate enters and stays within 1 mg and 0.1 mg of
  the true mass, for: the **baseline** (the settled reading: the 1 s moving average of the
  compensation force, every sample; and the first *stable* reading of ``ReadingFilter``, what a
  user waiting for the stability flag sees), the **dynamic estimator** (``DynamicWeigher``,
  Kalman, per sample) and the dynamic estimator averaged from the moment it flags itself
  settled;
* the resolution: standard deviation of consecutive 1 s readings at constant load;
* CPU per sample: the closed-loop simulator against the open-loop simulator at the same rate
  (the difference is the in-loop controller, its delay line and the precise channel), the
  compiled controller step alone, the interpreted ``RuntimeController.update`` (the external
  controller node's cost) and ``DynamicWeigher.update_block``.

Usage::

    ./tools/bench.sh bench_weighing [--steps 0.05 0.1 0.02] [--seeds 2] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import platform
import sys
import time
from typing import Dict, List

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))   # the working tree, not an installed copy

from emfc_ros.core.control.loop_config import LoopConfig  # noqa: E402
from emfc_ros.core.control.runtime import controller_step, RuntimeController  # noqa: E402
from emfc_ros.core.model.parameters import BalanceParameters  # noqa: E402
from emfc_ros.core.paths import config_file  # noqa: E402
from emfc_ros.core.sim.closed_loop import ClosedLoopSimulator  # noqa: E402
from emfc_ros.core.sim.simulator import Simulator  # noqa: E402
from emfc_ros.core.weighing import (compensation_force_N, DynamicWeigher,  # noqa: E402
                                    ReadingFilter, settled_reading, WeighingCalibration)

FS_HZ = 20000
LOOP = LoopConfig()     # the default in-loop design: 10 kHz, 130 Hz, no notch
TOLERANCES_KG = (1.0e-6, 1.0e-7)


def time_within(estimate_kg: np.ndarray, true_kg: float, tol_kg: float,
                valid_from: int = 0) -> float:
    """Seconds after the step until ``estimate`` enters and stays within ``tol``; nan never."""
    bad = np.nonzero(np.abs(estimate_kg - true_kg) > tol_kg)[0]
    bad = bad[bad >= valid_from]
    last = max(int(bad[-1]) + 1 if bad.size else 0, valid_from)
    if last >= estimate_kg.size:
        return float('nan')
    return last / FS_HZ


def moving_average(x: np.ndarray, n: int) -> np.ndarray:
    """``y[k]`` = mean of ``x[k-n+1 .. k]`` (nan for ``k < n - 1``)."""
    c = np.concatenate([[0.0], np.cumsum(x)])
    out = np.full(x.size, np.nan)
    out[n - 1:] = (c[n:] - c[:-n]) / n
    return out


def run_steps(params: BalanceParameters, seed: int, masses: List[float],
              seconds_after: float) -> List[Dict[str, float]]:
    """Calibrate, then step to each mass; the times of every estimator per step."""
    sim = Simulator(params, float(FS_HZ), seed=seed, reference_channels=False)
    loop = ClosedLoopSimulator(sim, LOOP)
    rows = loop.channel_names.index('position_m'), \
        loop.channel_names.index('coil_current_precise_A')
    motor = params.motor.coeffs_N_per_A_per_mm_pow

    def run(mass: float, seconds: float):
        loop.set_load(mass)
        out = loop.step_block(np.zeros((2, int(seconds * FS_HZ))))
        y = out[rows[0]]
        return y, compensation_force_N(out[rows[1]], y, motor)

    cal = WeighingCalibration.nominal(params.mechanics)
    _, f = run(0.0, 2.0)
    cal = cal.zeroed(settled_reading(f, FS_HZ, cal).mean_force_N)
    _, f = run(0.1, 2.0)
    cal = cal.adjusted(settled_reading(f, FS_HZ, cal).mean_force_N, 0.1)
    y, f = run(0.0, 2.0)
    weigher = DynamicWeigher(params.mechanics, float(FS_HZ))
    weigher.update_block(y, f)
    readings = ReadingFilter(float(FS_HZ), cal)
    readings.push(f, loop.sample_index - f.size)
    results = []
    previous = 0.0
    for mass in masses:
        first = loop.sample_index
        y, f = run(mass, seconds_after)
        detailed = weigher.update_block_detailed(y, f)
        m_dyn = weigher.mass_kg(detailed.pan_force_N, cal)
        m_avg = cal.mass_kg(moving_average(f, FS_HZ))
        # the flag is still up for the first samples after the step (the estimate has not
        # moved yet): average from its first rise after it has dropped
        flag = detailed.settled
        dropped = np.nonzero(~flag)[0]
        rises = np.nonzero(flag[dropped[0]:])[0] + dropped[0] if dropped.size else \
            np.array([], dtype=int)
        start = int(rises[0]) if rises.size else m_dyn.size
        m_dyn_avg = np.full(m_dyn.size, np.nan)
        if start < m_dyn.size:
            m_dyn_avg[start:] = np.cumsum(m_dyn[start:]) / np.arange(1, m_dyn.size - start + 1)
        stable = [r for r in readings.push(f, first) if r.stable]
        row = {'seed': seed, 'from_kg': previous, 'mass_kg': mass,
               'dynamic_flagged_settled_s': start / FS_HZ}
        for tol in TOLERANCES_KG:
            key = f'{tol * 1e6:g}mg'
            row[f'moving_average_{key}_s'] = time_within(m_avg, mass, tol, FS_HZ - 1)
            row[f'dynamic_{key}_s'] = time_within(m_dyn, mass, tol)
            row[f'dynamic_averaged_{key}_s'] = time_within(m_dyn_avg, mass, tol, start)
            ok = [r for r in stable if abs(r.mass_kg - mass) <= tol]
            bad_after = [r for r in stable if abs(r.mass_kg - mass) > tol]
            t_stable = float('nan')
            if ok:
                later = [r for r in ok if not bad_after or r.sample_index >
                         max(b.sample_index for b in bad_after)]
                if later:
                    t_stable = (later[0].sample_index + 1 - first) / FS_HZ
            row[f'stable_reading_{key}_s'] = t_stable
        tail = m_avg[-FS_HZ // 2:]
        row['settled_error_mg'] = float((np.mean(tail) - mass) * 1e6)
        results.append(row)
        previous = mass
    return results


def resolution_kg(params: BalanceParameters, seed: int, n_readings: int) -> float:
    """Standard deviation of consecutive 1 s readings at a constant 50 g."""
    loop = ClosedLoopSimulator(Simulator(params, float(FS_HZ), seed=seed,
                                         reference_channels=False), LOOP)
    loop.set_load(0.05)
    loop.step_block(np.zeros((2, FS_HZ)))
    out = loop.step_block(np.zeros((2, FS_HZ * n_readings)))
    names = loop.channel_names
    y = out[names.index('position_m')]
    f = compensation_force_N(out[names.index('coil_current_precise_A')], y,
                             params.motor.coeffs_N_per_A_per_mm_pow)
    cal = WeighingCalibration.nominal(params.mechanics)
    return float(np.std(cal.mass_kg(f.reshape(n_readings, FS_HZ).mean(axis=1)), ddof=1))


def cpu_costs(params: BalanceParameters, seconds: float, repeats: int) -> Dict[str, float]:
    """Nanoseconds per sample of the loop's parts, best of ``repeats``."""
    n = int(seconds * FS_HZ)
    u = np.zeros((2, n))

    def best(fn) -> float:
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
        return min(times)

    open_sim = Simulator(params, float(FS_HZ), seed=1)
    open_sim.set_load(0.0)
    hold = np.tile(open_sim.hold_setpoints_V[:, None], (1, n))
    open_sim.step_block(hold[:, :10])
    closed = ClosedLoopSimulator(Simulator(params, float(FS_HZ), seed=1), LOOP)
    closed.step_block(u[:, :10])
    t_open = best(lambda: open_sim.step_block(hold))
    t_closed = best(lambda: closed.step_block(u))
    import numba
    step = numba.njit(cache=True)(_controller_loop)
    coef = closed._coef.copy()
    state = closed.controller_state
    errors = np.random.default_rng(0).normal(scale=1e-9, size=n // 2)
    step(coef, state.copy(), errors[:10])
    t_ctrl = best(lambda: step(coef, state.copy(), errors))
    rc = RuntimeController(closed.design.controller)
    m = min(20000, errors.size)
    t_py = best(lambda: [rc.update(e) for e in errors[:m]])
    weigher = DynamicWeigher(params.mechanics, float(FS_HZ))
    y = np.random.default_rng(1).normal(scale=2e-9, size=n)
    f = np.full(n, 0.1667)
    weigher.update_block(y[:10], f[:10])
    t_dyn = best(lambda: weigher.update_block(y, f))
    return {
        'open_loop_simulator_ns_per_sample': t_open / n * 1e9,
        'closed_loop_simulator_ns_per_sample': t_closed / n * 1e9,
        'in_loop_overhead_ns_per_controller_sample': (t_closed - t_open) / (n / closed.ratio)
        * 1e9,
        'controller_step_compiled_ns': t_ctrl / errors.size * 1e9,
        'runtime_controller_interpreted_ns': t_py / m * 1e9,
        'dynamic_weigher_ns_per_sample': t_dyn / n * 1e9,
    }


def _controller_loop(coef, state, errors):
    acc = 0.0
    for e in errors:
        acc += controller_step(coef, state, e)
    return acc


def main(argv: List[str] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--steps', type=float, nargs='+', default=[0.05, 0.1, 0.02],
                        help='masses on the pan, one step each [kg]')
    parser.add_argument('--seeds', type=int, default=2)
    parser.add_argument('--seconds-after', type=float, default=5.0,
                        help='simulated time after each step [s]')
    parser.add_argument('--repeats', type=int, default=5)
    parser.add_argument('--json', type=Path, default=ROOT / 'bench' / 'results' /
                        'weighing.json')
    args = parser.parse_args(argv)
    params = BalanceParameters.load_yaml(str(config_file('balance_default.yaml')))
    print(f'{platform.processor() or platform.machine()}, python {platform.python_version()}; '
          f'simulator {FS_HZ} Hz, controller {LOOP.rate_Hz:g} Hz, crossover '
          f'{LOOP.crossover_Hz:g} Hz, notch {LOOP.notch_Hz:g} Hz', flush=True)
    t0 = time.perf_counter()
    steps = []
    for seed in range(1, args.seeds + 1):
        steps.extend(run_steps(params, seed, args.steps, args.seconds_after))
    print(f'\nload steps ({time.perf_counter() - t0:.1f} s wall); times after the step [s] '
          f'until within and staying within the tolerance (nan: not within '
          f'{args.seconds_after:g} s)')
    cols = [('moving_average', 'settled 1 s average'), ('stable_reading', 'first stable reading'),
            ('dynamic', 'dynamic (Kalman)'), ('dynamic_averaged', 'dynamic, then averaged')]
    print(f'{"step":>16s} ' + ' '.join(f'{label:>22s}' for _, label in cols))
    for row in steps:
        for tol in TOLERANCES_KG:
            key = f'{tol * 1e6:g}mg'
            label = f'{row["from_kg"] * 1e3:g}->{row["mass_kg"] * 1e3:g} g {key}'
            print(f'{label:>16s} ' + ' '.join(f'{row[f"{c}_{key}_s"]:22.3f}' for c, _ in cols))
    summary = {}
    for c, label in cols:
        for tol in TOLERANCES_KG:
            key = f'{tol * 1e6:g}mg'
            values = np.array([r[f'{c}_{key}_s'] for r in steps])
            summary[f'{c}_{key}_median_s'] = float(np.nanmedian(values)) if np.any(
                np.isfinite(values)) else float('nan')
            summary[f'{c}_{key}_never'] = int(np.sum(~np.isfinite(values)))
    medians = [f'{k} {v:.3f}' for k, v in summary.items() if k.endswith('_s')]
    print('\nmedians [s]: ' + ', '.join(medians))
    res = resolution_kg(params, 7, 10)
    print(f'resolution: std of 1 s readings at 50 g = {res * 1e9:.1f} ug')
    costs = cpu_costs(params, 2.0, args.repeats)
    print('CPU per sample: ' + ', '.join(f'{k} {v:.0f}' for k, v in costs.items()))
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({'steps': steps, 'summary': summary,
                                     'resolution_kg': res, 'cpu': costs,
                                     'machine': platform.platform()}, indent=1))
    print(f'written {args.json}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
