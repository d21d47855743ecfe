"""
Accuracy and speed of the identification pipeline on the simulated balance (issue item 6).

The shipped four-section trajectory (``config/identification_trajectory.yaml``, 4 x 10 s at
10 kHz), scaled to stay inside the sensor range (``DEFAULT_TRAJECTORY_GAINS``), is played
through the simulator with the default parameters, realistic noise and quantisation, the pan
loaded with the balancing mass and the load changer coupled. The pipeline starts its grey-box
model from perturbed mechanics (c1 +20 %, d1 -17 %, c2 -8 %, d2 +23 %, F_off 0.1 mN) and is
compared with the linear model of the same configuration and with the true parameters:

* resonance (target 0.5 %), anti-resonance (1 %), modal damping (10 %) of the TF fits;
* grey-box stiffness and damping (2 %; 0.1 % on a noise-free, unquantised run); fit % per
  section (>= 95 %);
* wall time of each step; least squares against pattern search on the same problem;
* LPM and Welch FRF of 10^6 samples (target < 2 s), and the Welch H1 of the coil chirp as the
  baseline of the LPM's accuracy.

    .venv/bin/python bench/bench_ident_balance.py --json bench/results/ident_balance.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import platform
import sys
import time
from typing import Dict, List, Optional

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))   # the working tree, not an installed copy

from emfc_ros.core.ident import estimate_frf, select_order  # noqa: E402
from emfc_ros.core.ident.balance_experiment import (DEFAULT_TRAJECTORY_GAINS,  # noqa: E402
                                                    scaled_experiment, section_table,
                                                    simulate_experiment)
from emfc_ros.core.ident.local_polynomial import local_polynomial_frf  # noqa: E402
from emfc_ros.core.ident.pipeline import hold_factor, identify  # noqa: E402
from emfc_ros.core.model.linear import linearise  # noqa: E402
from emfc_ros.core.model.load import loaded  # noqa: E402
from emfc_ros.core.model.parameters import BalanceParameters  # noqa: E402
from emfc_ros.core.signals import load_experiment_file  # noqa: E402

TRAJECTORY = ROOT / 'config' / 'identification_trajectory.yaml'
TRUTH = BalanceParameters()
START = TRUTH.with_mechanics(c1_Nm_per_rad=0.12, d1_Nms_per_rad=3.5e-4, c2_Nm_per_rad=19.0,
                             d2_Nms_per_rad=2.8e-4, F_off_N=1.0e-4)
FREE = ('c1_Nm_per_rad', 'd1_Nms_per_rad', 'c2_Nm_per_rad', 'd2_Nms_per_rad')


def rel(a: float, b: float) -> float:
    return float(a / b - 1.0)


def truth_roots(load_mass_kg: float) -> Dict[str, list]:
    lin = linearise(loaded(TRUTH.mechanics, load_mass_kg, True))
    poles = [p for p in lin.poles() if p.s_rad_per_s.imag > 0]
    zeros = [z for z in lin.zeros('coil') if z.s_rad_per_s.imag > 0]
    return {'poles': poles, 'zeros': zeros, 'model': lin}


def frf_rows(res, truth) -> List[Dict]:
    rows = []
    for r in res.frfs:
        if r.fit is None:
            continue
        c = r.fit.chosen
        row = {'frf': r.name, 'order': f'{c.numerator_order}/{c.denominator_order}'}
        for label, mode, ref in (('low', c.modes[0], truth['poles'][0]),
                                 ('high', c.modes[-1], truth['poles'][-1])):
            row[f'{label}_mode_Hz'] = mode.frequency_Hz
            row[f'{label}_mode_std_Hz'] = mode.frequency_std_Hz
            row[f'{label}_mode_error'] = rel(mode.frequency_Hz, ref.frequency_Hz)
            row[f'{label}_damping'] = mode.damping_ratio
            row[f'{label}_damping_std'] = mode.damping_std
            row[f'{label}_damping_error'] = rel(mode.damping_ratio, ref.damping_ratio)
        if c.anti_resonances:
            a = c.anti_resonances[0]
            row['anti_resonance_Hz'] = a.frequency_Hz
            row['anti_resonance_std_Hz'] = a.frequency_std_Hz
            row['anti_resonance_error'] = rel(a.frequency_Hz, truth['zeros'][0].frequency_Hz)
        rows.append(row)
    return rows


def greybox_row(res, label: str) -> Optional[Dict]:
    if res.greybox is None:     # the fit refused to run (fail closed); the reason is printed
        print(f'grey-box on {label}: no result: {"; ".join(res.failures)}')
        return None
    fit = res.greybox.fit
    row = {'case': label, 'method': fit.method, 'evaluations': fit.optimizer_evaluations,
           'time_s': fit.time_s, 'success': fit.success,
           'min_fit_percent': min(float(np.min(s.fit_percent)) for s in fit.sections),
           'fit_percent': {s.name: float(np.min(s.fit_percent)) for s in fit.sections},
           # the fit's offset parameter is the rest position since issue 12; F_off_N is
           # derived from it, with its uncertainty
           'F_off_N': res.greybox.derived['F_off_N'].value,
           'F_off_std_N': res.greybox.derived['F_off_N'].standard_uncertainty,
           'simulations': fit.n_evaluations}
    for name in FREE:
        row[f'{name}_error'] = rel(fit.parameters[name], getattr(TRUTH.mechanics, name))
        row[f'{name}_std_rel'] = fit.standard_errors[name] / getattr(TRUTH.mechanics, name)
    row['max_parameter_error'] = max(abs(row[f'{n}_error']) for n in FREE)
    row['steps_s'] = dict(res.timings_s)
    return row


def welch_baseline(rec, truth) -> Dict:
    span = rec.sections[0]
    sl = slice(span.first_sample_index, span.first_sample_index + span.n_samples)
    frd = estimate_frf(rec.channels['coil_force_N'][sl], rec.channels['position_m'][sl],
                       rec.sample_rate_Hz, nperseg=8192, input_unit='N', output_unit='m')
    frd = frd.band(5.0, 1500.0)
    fac = hold_factor(frd.frequency_Hz, rec.sample_rate_Hz, 'zoh')
    frd.response[:] = frd.response / fac
    fit = select_order(frd, [(0, 2), (2, 4), (3, 4), (4, 6)]).chosen
    high = fit.modes[-1]
    out = {'estimator': 'Welch H1, nperseg 8192', 'order':
           f'{fit.numerator_order}/{fit.denominator_order}',
           'high_mode_error': rel(high.frequency_Hz, truth['poles'][-1].frequency_Hz),
           'high_damping_error': rel(high.damping_ratio, truth['poles'][-1].damping_ratio)}
    if fit.anti_resonances:
        out['anti_resonance_error'] = rel(fit.anti_resonances[0].frequency_Hz,
                                          truth['zeros'][0].frequency_Hz)
    return out


def frf_speed(n: int) -> Dict:
    rng = np.random.default_rng(0)
    u = rng.standard_normal(n)
    y = np.convolve(u, np.exp(-np.arange(200) / 20.0), mode='same') + 0.01 * rng.standard_normal(n)
    out = {'n_samples': n}
    for name, run in (('lpm_s', lambda: local_polynomial_frf([u], y, 10000.0)),
                      ('lpm_two_input_s', lambda: local_polynomial_frf([u, y[::-1].copy()], y,
                                                                       10000.0)),
                      ('welch_h1_s', lambda: estimate_frf(u, y, 10000.0, nperseg=8192))):
        best = float('inf')
        for _ in range(3):
            start = time.perf_counter()
            run()
            best = min(best, time.perf_counter() - start)
        out[name] = best
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--json', default=str(ROOT / 'bench' / 'results' / 'ident_balance.json'))
    parser.add_argument('--seed', type=int, default=1)
    parser.add_argument('--skip-pattern-search', action='store_true')
    args = parser.parse_args()

    exp = scaled_experiment(load_experiment_file(TRAJECTORY), DEFAULT_TRAJECTORY_GAINS)
    t0 = time.perf_counter()
    rec = simulate_experiment(TRUTH, exp, seed=args.seed)
    sim_s = time.perf_counter() - t0
    truth = truth_roots(rec.load_mass_kg)
    peaks = {s.name: float(np.abs(rec.channels['position_true_m'][
        s.first_sample_index:s.first_sample_index + s.n_samples]).max())
        for s in rec.sections}
    amplitudes = {}
    for sec in exp.sections:
        for ch, plan in sec.channels.items():
            amplitudes[f'{sec.name}.{ch}'] = plan.gain
    cfg = {'load_mass_kg': rec.load_mass_kg, 'load_changer_coupled': True,
           'balance': START.to_mapping()}

    t0 = time.perf_counter()
    res = identify(rec, section_table(rec), cfg)
    total_s = time.perf_counter() - t0
    rows = frf_rows(res, truth)
    gb = [greybox_row(res, 'noise + quantisation')]

    if not args.skip_pattern_search:
        ps_cfg = dict(cfg, greybox={'method': 'pattern_search'})
        gb.append(greybox_row(identify(rec, section_table(rec), ps_cfg), 'noise + quantisation'))

    clean = simulate_experiment(TRUTH, exp, seed=args.seed, noise=False, quantisation=False)
    clean_res = identify(clean, section_table(clean), cfg)
    gb.append(greybox_row(clean_res, 'noise-free, unquantised'))
    gb = [row for row in gb if row is not None]
    clean_rows = frf_rows(clean_res, truth)

    baseline = welch_baseline(rec, truth)
    speed = frf_speed(10 ** 6)

    print(f'trajectory: {exp.total_samples} samples at {exp.sample_rate_Hz:g} Hz, simulated '
          f'in {sim_s:.2f} s; load {rec.load_mass_kg:.5f} kg, load changer coupled')
    print('channel gains applied to the shipped trajectory: ' +
          ', '.join(f'{k} x{v:g}' for k, v in DEFAULT_TRAJECTORY_GAINS.items()))
    print('peak |y| per section [um]: ' + ', '.join(f'{k} {1e6 * v:.1f}'
                                                    for k, v in peaks.items()))
    print(f'\ntruth: modes {truth["poles"][0].frequency_Hz:.4f} Hz (zeta '
          f'{truth["poles"][0].damping_ratio:.5f}), {truth["poles"][-1].frequency_Hz:.4f} Hz '
          f'(zeta {truth["poles"][-1].damping_ratio:.5f}); coil anti-resonance '
          f'{truth["zeros"][0].frequency_Hz:.4f} Hz')
    print('\n| FRF (data) | order | resonance err | damping err | low mode err | low damping '
          'err | anti-resonance err |')
    print('|---|---|---|---|---|---|---|')
    for label, rr in (('noisy', rows), ('clean', clean_rows)):
        for r in rr:
            anti = f'{100 * r["anti_resonance_error"]:+.3f} %' if 'anti_resonance_error' in r \
                else '-'
            print(f'| {r["frf"]} ({label}) | {r["order"]} | {100 * r["high_mode_error"]:+.3f} % '
                  f'| {100 * r["high_damping_error"]:+.2f} % | '
                  f'{100 * r["low_mode_error"]:+.3f} % | {100 * r["low_damping_error"]:+.2f} % '
                  f'| {anti} |')
    print(f'| baseline {baseline["estimator"]} coil (noisy) | {baseline["order"]} | '
          f'{100 * baseline["high_mode_error"]:+.3f} % | '
          f'{100 * baseline["high_damping_error"]:+.2f} % | | | '
          f'{100 * baseline.get("anti_resonance_error", float("nan")):+.3f} % |')
    print('\n| grey-box case | method | evaluations | time [s] | c1 err | d1 err | c2 err | '
          'd2 err | F_off [N] | min fit % |')
    print('|---|---|---|---|---|---|---|---|---|---|')
    for r in gb:
        print(f'| {r["case"]} | {r["method"]} | {r["evaluations"]} | {r["time_s"]:.1f} | ' +
              ' | '.join(f'{100 * r[f"{n}_error"]:+.4f} %' for n in FREE) +
              f' | {r["F_off_N"]:.2e} | {r["min_fit_percent"]:.2f} |')
    print('\nfit % per section (default optimiser, noisy): ' +
          ', '.join(f'{k} {v:.2f}' for k, v in gb[0]['fit_percent'].items()))
    print('wall time per step [s] (default optimiser, noisy): ' +
          ', '.join(f'{k} {v:.2f}' for k, v in res.timings_s.items()) + f'; total {total_s:.2f}')
    print(f'FRF of 10^6 samples: LPM {speed["lpm_s"]:.3f} s, LPM two inputs '
          f'{speed["lpm_two_input_s"]:.3f} s, Welch H1 {speed["welch_h1_s"]:.3f} s')
    print('warnings: ' + ('; '.join(res.warnings) or 'none'))

    out = {'machine': {'python': platform.python_version(), 'platform': platform.platform()},
           'trajectory': {'file': str(TRAJECTORY.relative_to(ROOT)), 'gains': amplitudes,
                          'n_samples': exp.total_samples, 'sample_rate_Hz': exp.sample_rate_Hz,
                          'peak_position_m': peaks, 'load_mass_kg': rec.load_mass_kg,
                          'load_changer_coupled': True, 'seed': args.seed,
                          'simulation_s': sim_s},
           'truth': {'low_mode_Hz': truth['poles'][0].frequency_Hz,
                     'low_damping': truth['poles'][0].damping_ratio,
                     'high_mode_Hz': truth['poles'][-1].frequency_Hz,
                     'high_damping': truth['poles'][-1].damping_ratio,
                     'anti_resonance_Hz': truth['zeros'][0].frequency_Hz},
           'frf_fits_noisy': rows, 'frf_fits_clean': clean_rows, 'welch_baseline': baseline,
           'greybox': gb, 'steps_s': res.timings_s, 'total_s': total_s, 'frf_speed': speed,
           'warnings': res.warnings}
    path = Path(args.json)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=2))
    print(f'\nwrote {path}')


if __name__ == '__main__':
    main()
