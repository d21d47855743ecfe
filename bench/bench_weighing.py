"""
Weighing on the simulated closed loop: time from a load step to a reading within 1 mg for good.

One run, the same simulated data for every estimator (issue 15, item 5):

* the balance in closed loop at the plant_simulator node's defaults (simulator and controller
  at 10 kHz, the default in-loop design: 130 Hz, no notch; noise and quantisation on), zeroed
  with the empty pan and adjusted with a 100 g reference weight; then, per seed, steps of
  1, 10, 50, 100 and 200 g up from a random base load and back down (2 s each);
* after each step, the time until the estimate enters and stays within 1 mg of the true mass:
  the **baseline**, the 1-s moving average of the compensation force (every sample), and the
  first *stable* reading of the weighing pipeline (what a user waiting for the stability flag
  sees, released after its look-ahead); the **dynamic estimate** (change-adaptive Kalman, per
  sample), the first *settled* dynamic reading, and the former steady-state Kalman filter
  (``q = 1e-5``) for comparison; the largest lever excursion (the sensor range is 100 um);
* what limits the dynamic estimate: the last load change the estimator declared (while the
  lever moves, the model error makes the innovation test fire again and again), the noise
  (when the filter's own standard deviation, which after a declared change shrinks as the
  data come in, has fallen so that 3 sigma are below 1 mg), and the loop and model error
  (when the true lever position has settled within
  10 nm: while the lever moves, the load's inertia, which the empty-pan model lacks, and the
  sensor's and motor's nonlinearity disturb the estimate); the estimate's noise at constant
  load;
* CPU per sample of the closed-loop simulator, the adaptive and the steady-state estimator.

Seeds (default 1001-1003) and base loads were not used to tune the estimator.

Usage::

    ./tools/bench.sh bench_weighing [--seeds 3] [--sizes 0.001 0.01 0.05 0.1 0.2] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
import platform
import sys
import time
from typing import Dict, List

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))   # the working tree, not an installed copy

from emfc_ros.core.control.loop_config import LoopConfig  # noqa: E402
from emfc_ros.core.model.parameters import BalanceParameters  # noqa: E402
from emfc_ros.core.paths import config_file  # noqa: E402
from emfc_ros.core.sim.closed_loop import ClosedLoopSimulator  # noqa: E402
from emfc_ros.core.sim.resolution import simulator_resolution  # noqa: E402
from emfc_ros.core.sim.simulator import Simulator  # noqa: E402
from emfc_ros.core.weighing import (compensation_force_N, DynamicWeigher,  # noqa: E402
                                    settled_reading, WeighingCalibration)
from emfc_ros.core.weighing.pipeline import WeighingPipeline  # noqa: E402

FS_HZ = 10000.0
SEGMENT_S = 2.0
TOL_KG = 1.0e-6
LOOP = LoopConfig()
COLUMNS = (('moving_average', '1-s moving average'),
           ('stable_reading', 'stable reading out'),
           ('dynamic', 'dynamic (adaptive)'),
           ('settled_dynamic', 'settled dynamic out'),
           ('steady_state_kalman', 'steady-state Kalman'),
           ('last_change', 'last change declared'),
           ('noise_limit', '3 sigma below 1 mg'),
           ('lever_settled', 'lever within 10 nm'))


def time_within(estimate: np.ndarray, true: np.ndarray, start: int, stop: int) -> float:
    """Seconds after ``start`` until the estimate is within 1 mg for good (nan: never)."""
    bad = np.nonzero(~(np.abs(estimate[start:stop] - true[start:stop]) <= TOL_KG))[0]
    last = int(bad[-1]) + 1 if bad.size else 0
    return float('nan') if last >= stop - start else last / FS_HZ


def schedule(seed: int, sizes: List[float]) -> np.ndarray:
    """Empty, 100 g (adjustment), empty, then each size up from a random base and down."""
    rng = np.random.default_rng(seed)
    levels = [0.0, 0.1, 0.0]
    for size in sizes:
        base = float(rng.uniform(0.0, max(0.0, 0.2 - size)))
        levels += [base, base + size, base]
    return np.repeat(levels, int(SEGMENT_S * FS_HZ))


def simulate(params: BalanceParameters, seed: int, load: np.ndarray, noise: bool = True):
    loop = ClosedLoopSimulator(Simulator(params, FS_HZ, seed=seed, reference_channels=True,
                                         noise=noise, quantisation=noise), LOOP)
    out = loop.step_loads(load)
    names = loop.channel_names
    y = out[names.index('position_m')]
    current = out[names.index('coil_current_precise_A')]
    force = compensation_force_N(current, y, params.motor.coeffs_N_per_A_per_mm_pow)
    return y, current, force, out[names.index('position_true_m')]


def calibrate(params: BalanceParameters, force: np.ndarray) -> WeighingCalibration:
    n = int(SEGMENT_S * FS_HZ)
    cal = WeighingCalibration.nominal(params.mechanics)
    cal = cal.zeroed(settled_reading(force[:n], FS_HZ, cal).mean_force_N)
    return cal.adjusted(settled_reading(force[n:2 * n], FS_HZ, cal).mean_force_N, 0.1)


def position_noise(params: BalanceParameters) -> float:
    res = simulator_resolution(params)['position_m']
    return math.hypot(res['noise_rms'], res['step'] / math.sqrt(12.0))


def run_seed(params: BalanceParameters, seed: int, sizes: List[float]) -> List[Dict]:
    load = schedule(seed, sizes)
    n = int(SEGMENT_S * FS_HZ)
    y, current, force, y_true = simulate(params, seed, load)
    cal = calibrate(params, force)
    noise = position_noise(params)
    adaptive = DynamicWeigher(params.mechanics, FS_HZ, position_noise_m_rms=noise)
    estimate = adaptive.update_block_detailed(y, force)
    m_dyn = adaptive.mass_kg(estimate.pan_force_N, cal)
    u_kg = adaptive.mass_u_kg(estimate.pan_force_u_N, cal)
    steady = DynamicWeigher(params.mechanics, FS_HZ, position_noise_m_rms=noise,
                            force_random_walk_N_per_sqrt_s=1e-5, adaptive=False)
    m_ss = steady.mass_kg(steady.update_block(y, force), cal)
    c = np.concatenate(([0.0], np.cumsum(force)))
    w = int(FS_HZ)                                                      # 1 s
    average = np.full(force.size, np.nan)
    average[w - 1:] = (c[w:] - c[:-w]) / w
    m_avg = cal.mass_kg(average)
    pipe = WeighingPipeline(params.mechanics, params.motor.coeffs_N_per_A_per_mm_pow, FS_HZ,
                            cal, calibrated=True, position_noise_m_rms=noise)
    pipe_lookahead = int(round(0.1 * FS_HZ))      # one reading period
    dynamic_lookahead = int(round(0.02 * FS_HZ))  # the settle window
    readings, dynamic = [], []
    for a in range(0, load.size, 1000):
        r, d = pipe.push(current[a:a + 1000], y[a:a + 1000], a)
        readings += r
        dynamic += d
    rows = []
    sizes_g = {round(size * 1e3, 6) for size in sizes}
    for k in range(3, load.size // n):
        start, stop = k * n, (k + 1) * n
        before, after = float(load[start - 1]), float(load[start])
        step_g = round(abs(after - before) * 1e3, 6)
        if step_g not in sizes_g:
            continue                        # from one size's base to the next size's
        true = load
        row = {'seed': seed, 'from_kg': before, 'to_kg': after, 'step_g': step_g,
               'lever_peak_um': float(np.max(np.abs(y_true[start:stop])) * 1e6)}
        row['moving_average_s'] = time_within(m_avg, true, start, stop)
        row['dynamic_s'] = time_within(m_dyn, true, start, stop)
        row['steady_state_kalman_s'] = time_within(m_ss, true, start, stop)
        declared = np.nonzero(estimate.change[start:stop])[0]
        row['last_change_s'] = (declared[-1] + 1) / FS_HZ if declared.size else 0.0
        big = np.nonzero(3.0 * u_kg[start:stop] >= TOL_KG)[0]
        row['noise_limit_s'] = (big[-1] + 1) / FS_HZ if big.size else 0.0
        moving = np.nonzero(np.abs(y_true[start:stop]) > 1e-8)[0]
        row['lever_settled_s'] = (moving[-1] + 1) / FS_HZ if moving.size else 0.0
        stable = [r for r in readings if start <= r.sample_index < stop and r.stable]
        good = [r for r in stable if abs(r.mass_kg - after) <= TOL_KG]
        # when the user has it: released one reading period after its last sample
        row['stable_reading_s'] = ((good[0].sample_index + 1 + pipe_lookahead - start) / FS_HZ
                                   if good else float('nan'))
        row['stable_reading_wrong'] = len(stable) - len(good)
        settled = [d for d in dynamic if start <= d.sample_index < stop and d.settled]
        ok = [d for d in settled if abs(d.mass_kg - after) <= TOL_KG]
        row['settled_dynamic_s'] = ((ok[0].sample_index + 1 + dynamic_lookahead - start)
                                    / FS_HZ if ok else float('nan'))
        row['settled_dynamic_wrong'] = len(settled) - len(ok)
        rows.append(row)
    return rows


def noise_mg(params: BalanceParameters, seed: int) -> Dict[str, float]:
    """Estimate noise at a constant 50 g (after 1 s) and the std of 1-s readings."""
    load = np.full(int(6 * FS_HZ), 0.05)
    y, _, force, _ = simulate(params, seed, load)
    cal = WeighingCalibration.nominal(params.mechanics)
    weigher = DynamicWeigher(params.mechanics, FS_HZ, position_noise_m_rms=position_noise(params))
    m = weigher.mass_kg(weigher.update_block(y, force), cal)[int(FS_HZ):]
    ones = cal.mass_kg(force[int(FS_HZ):].reshape(5, -1).mean(axis=1))
    return {'dynamic_noise_mg_rms': float(np.std(m) * 1e6),
            'dynamic_peak_to_peak_mg': float(np.ptp(m) * 1e6),
            'moving_average_1s_std_mg': float(np.std(ones, ddof=1) * 1e6)}


def loop_table(params: BalanceParameters) -> List[Dict]:
    """The default in-loop design and the former one (100 Hz, notch at 410 Hz) over 0..200 g."""
    from emfc_ros.core.control.robust import load_margins
    from emfc_ros.core.sim.closed_loop import design_for
    from emfc_ros.core.weighing import WeighingCalibration as Cal
    out = []
    sensitivity = Cal.nominal(params.mechanics).sensitivity_kg_per_N
    for name, config in (('default (130 Hz, no notch)', LOOP),
                         ('former (100 Hz, notch 410 Hz)',
                          LoopConfig(crossover_Hz=100.0, notch_Hz=410.0, max_load_kg=0.0))):
        design = design_for(Simulator(params, FS_HZ, seed=0), config)
        for load in (0.0, 0.05, 0.1, 0.2):
            m = load_margins(params.mechanics, design.controller, config.delay_samples, load)
            sim = Simulator(params, FS_HZ, seed=0, noise=False, quantisation=False)
            loop = ClosedLoopSimulator(sim, config, design=design)
            n = int(0.6 * FS_HZ)
            out_ = loop.step_loads(np.concatenate((np.zeros(int(0.3 * FS_HZ)), np.full(n, load))))
            force = out_[loop.channel_names.index('coil_force_true_N'), -n:]
            y = out_[loop.channel_names.index('position_true_m'), -n:]
            after = np.abs(sensitivity * (force - force[-1]))[int(0.1 * FS_HZ):]
            out.append({'design': name, 'load_g': load * 1e3, 'mode_Hz': m.mode_Hz,
                        'crossover_Hz': m.crossover_Hz, 'sensitivity_peak': m.sensitivity_peak,
                        'lower_gm_dB': m.lower_gain_margin_dB,
                        'upper_gm_dB': m.upper_gain_margin_dB,
                        'pole_radius': m.pole_radius,
                        'step_deviation_after_100ms_mg': float(after.max() * 1e6),
                        'lever_peak_um': float(np.abs(y).max() * 1e6)})
    return out


def cpu_costs(params: BalanceParameters, repeats: int) -> Dict[str, float]:
    n = int(2 * FS_HZ)

    def best(fn) -> float:
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
        return min(times)

    loop = ClosedLoopSimulator(Simulator(params, FS_HZ, seed=1), LOOP)
    loop.step_block(np.zeros((2, 10)))
    u = np.zeros((2, n))
    t_loop = best(lambda: loop.step_block(u))
    y = np.random.default_rng(1).normal(scale=2.7e-9, size=n)
    f = np.full(n, 0.1667)
    adaptive = DynamicWeigher(params.mechanics, FS_HZ, position_noise_m_rms=2.7e-9)
    adaptive.update_block(y[:10], f[:10])
    steady = DynamicWeigher(params.mechanics, FS_HZ, position_noise_m_rms=2.7e-9,
                            adaptive=False)
    steady.update_block(y[:10], f[:10])
    return {'closed_loop_simulator_ns_per_sample': best(lambda: loop.step_block(u)) / n * 1e9
            if t_loop else 0.0,
            'adaptive_weigher_ns_per_sample': best(lambda: adaptive.update_block(y, f)) / n
            * 1e9,
            'steady_state_weigher_ns_per_sample': best(lambda: steady.update_block(y, f)) / n
            * 1e9}


def main(argv: List[str] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--sizes', type=float, nargs='+',
                        default=[0.001, 0.01, 0.05, 0.1, 0.2], help='step sizes [kg]')
    parser.add_argument('--seeds', type=int, default=3)
    parser.add_argument('--first-seed', type=int, default=1001)
    parser.add_argument('--repeats', type=int, default=3)
    parser.add_argument('--json', type=Path, default=ROOT / 'bench' / 'results' /
                        'weighing.json')
    args = parser.parse_args(argv)
    params = BalanceParameters.load_yaml(str(config_file('balance_default.yaml')))
    print(f'{platform.processor() or platform.machine()}, python {platform.python_version()}; '
          f'simulator and controller {FS_HZ:g} Hz, crossover {LOOP.crossover_Hz:g} Hz, '
          f'notch {LOOP.notch_Hz}', flush=True)
    t0 = time.perf_counter()
    rows = []
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        rows += run_seed(params, seed, args.sizes)
    print(f'\nsteps ({time.perf_counter() - t0:.1f} s wall): seconds after the step until '
          'within 1 mg for good (nan: not within 2 s)')
    print(f'{"seed":>5s} {"step":>16s} {"lever":>8s} '
          + ' '.join(f'{label:>22s}' for _, label in COLUMNS))
    for r in rows:
        step = f'{r["from_kg"] * 1e3:.1f}->{r["to_kg"] * 1e3:.1f} g'
        print(f'{r["seed"]:5d} {step:>16s} {r["lever_peak_um"]:6.1f}um '
              + ' '.join(f'{r[f"{c}_s"]:22.3f}' for c, _ in COLUMNS))
    summary = {}
    for size in sorted({r['step_g'] for r in rows}):
        sel = [r for r in rows if r['step_g'] == size]
        summary[f'{size:g} g'] = {c: float(np.nanmax([r[f'{c}_s'] for r in sel]))
                                  if any(np.isfinite(r[f'{c}_s']) for r in sel)
                                  else float('nan') for c, _ in COLUMNS}
        summary[f'{size:g} g']['never'] = {c: int(sum(not np.isfinite(r[f'{c}_s'])
                                                      for r in sel)) for c, _ in COLUMNS}
        summary[f'{size:g} g']['lever_peak_um'] = float(max(r['lever_peak_um'] for r in sel))
    print('\nworst over seeds and directions [s]:')
    print(f'{"step":>8s} ' + ' '.join(f'{label:>22s}' for _, label in COLUMNS)
          + f' {"lever peak":>11s}')
    for size, values in summary.items():
        print(f'{size:>8s} ' + ' '.join(f'{values[c]:22.3f}' for c, _ in COLUMNS)
              + f' {values["lever_peak_um"]:9.1f}um')
    up_to_100 = [r['dynamic_s'] for r in rows if r['step_g'] <= 100.0]
    print(f'\ndynamic, every step up to 100 g: worst {np.nanmax(up_to_100):.3f} s (target '
          f'0.15 s, moonshot 0.05 s); never within 1 mg: '
          f'{sum(not np.isfinite(t) for t in up_to_100)}')
    wrong = sum(r['stable_reading_wrong'] + r['settled_dynamic_wrong'] for r in rows)
    print(f'stable readings or settled dynamic readings more than 1 mg off: {wrong}')
    loops = loop_table(params)
    print('\nthe loop over the weighing range (margins of the loaded model; a step from 0 g to '
          'the load without noise: largest coil-force deviation after 100 ms, lever peak):')
    for r in loops:
        print(f'  {r["design"]:30s} {r["load_g"]:5.0f} g: mode {r["mode_Hz"]:5.1f} Hz, '
              f'crossover {r["crossover_Hz"]:5.1f} Hz, Ms {r["sensitivity_peak"]:5.2f}, gain '
              f'margins {r["lower_gm_dB"]:.1f} / {r["upper_gm_dB"]:.1f} dB, poles |z| <= '
              f'{r["pole_radius"]:.4f}; step: {r["step_deviation_after_100ms_mg"]:.3f} mg after '
              f'100 ms, lever {r["lever_peak_um"]:.1f} um')
    noise = noise_mg(params, args.first_seed + args.seeds)
    print('noise at 50 g: ' + ', '.join(f'{k} {v:.4f}' for k, v in noise.items()))
    costs = cpu_costs(params, args.repeats)
    print('CPU: ' + ', '.join(f'{k} {v:.0f}' for k, v in costs.items()))
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({'steps': rows, 'summary': summary, 'noise': noise,
                                     'loops': loops,
                                     'cpu': costs, 'machine': platform.platform()}, indent=1))
    print(f'written {args.json}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
