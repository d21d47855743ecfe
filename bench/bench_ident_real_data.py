"""
The identification tools on real, public measurements (issue item 8; benchmark only).

The data stay where they are (``--datasets``, never copied into the repository):

* F-16 ground vibration test, full-band multisine, lowest level
  (``f16-gvt/F16Data_FullMSine_Level1.csv``; Noel and Schoukens, "F-16 aircraft benchmark
  based on ground vibration test data", Workshop on Nonlinear System Identification
  Benchmarks, 2017): FRF of each acceleration per shaker force by period averaging
  (:func:`average_periods`, 9 periods x 8192 samples at 400 Hz, first period dropped), and a
  modal fit (:func:`select_order`) of the 3-15 Hz band: modal frequencies and damping with
  standard deviations.
* Silverbox (electronic Duffing oscillator; Wigren and Schoukens, "Three free data sets for
  development and benchmarking in nonlinear system identification", ECC 2013):
  - the FRF of the Schroeder multisine (``silverbox/Schroeder80mV.csv``, 131072 samples at
    610.35 Hz) by the local polynomial method (as the pipeline), and a second-order fit;
  - a Duffing grey-box fit through :func:`fit_greybox` (``m y'' + d y' + k y + k3 y^3 = u``
    with m = 1, an input gain, an output offset and optionally an input offset, the DC
    operating point that makes the cubic spring asymmetric; RK4 with first-order-hold input,
    4 steps per sample, numba; pattern search with MATLAB's default options)
    on the multisine part of ``silverbox/SNLS80mV.csv`` after sample 40650, tested on the
    arrow section (samples 100..40575): RMS error [mV], both optimisers' evaluations and time.

    .venv/bin/python bench/bench_ident_real_data.py --datasets /work/shared/datasets
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

from emfc_ros.core.ident import (average_periods, DataSection, fit_greybox,  # noqa: E402
                                 ParameterSpec, select_order)
from emfc_ros.core.ident.local_polynomial import local_polynomial_frf  # noqa: E402

F16_FILE = 'f16-gvt/F16Data_FullMSine_Level1.csv'
SCHROEDER_FILE = 'silverbox/Schroeder80mV.csv'
SNLS_FILE = 'silverbox/SNLS80mV.csv'
SILVERBOX_FS_HZ = 1.0e7 / 2 ** 14        # 610.35 Hz
SOURCES = {
    'f16': 'Noel and Schoukens, F-16 aircraft benchmark based on ground vibration test data, '
           'Workshop on Nonlinear System Identification Benchmarks, 2017',
    'silverbox': 'Wigren and Schoukens, Three free data sets for development and benchmarking '
                 'in nonlinear system identification, ECC 2013',
}


def read_csv(path: Path) -> Dict[str, np.ndarray]:
    with open(path, encoding='utf-8') as stream:
        header = [h.strip().strip('"') for h in stream.readline().split(',')]
    data = np.genfromtxt(path, delimiter=',', skip_header=1)
    return {name: data[:, i] for i, name in enumerate(header) if name}


# ---------------------------------------------------------------- F-16


def f16(root: Path) -> Dict:
    cols = read_csv(root / F16_FILE)
    fs = float(cols['Fs'][0])
    period = 8192
    force = cols['Force']
    rows = []
    for ch in ('Acceleration1', 'Acceleration2', 'Acceleration3'):
        start = time.perf_counter()
        frd = average_periods(force, cols[ch], fs, period, transient_periods=1,
                              input_unit='N', output_unit='m/s^2')
        t_frf = time.perf_counter() - start
        band = frd.band(3.0, 15.0)
        start = time.perf_counter()
        sel = select_order(band, [(n, n) for n in (4, 6, 8, 10, 12)], criterion='bic')
        t_fit = time.perf_counter() - start
        c = sel.chosen
        modes = [{'frequency_Hz': m.frequency_Hz, 'frequency_std_Hz': m.frequency_std_Hz,
                  'damping_ratio': m.damping_ratio, 'damping_std': m.damping_std}
                 for m in c.modes if 3.0 <= m.frequency_Hz <= 15.0]
        rel = np.abs(c.response(band.frequency_Hz) - band.response) / np.abs(band.response)
        rows.append({'channel': ch, 'n_lines_3_15_Hz': int(band.frequency_Hz.size),
                     'median_rel_std': float(np.median(band.std / np.abs(band.response))),
                     'order': f'{c.numerator_order}/{c.denominator_order}',
                     'median_rel_fit_error': float(np.median(rel)), 'modes': modes,
                     'frf_s': t_frf, 'fit_s': t_fit,
                     'bic_table': [{k: v for k, v in r.items()} for r in sel.table]})
    return {'file': F16_FILE, 'source': SOURCES['f16'], 'sample_rate_Hz': fs,
            'periods': int(force.size // period), 'period_samples': period, 'channels': rows}


# ---------------------------------------------------------------- Silverbox FRF


def schroeder(root: Path) -> Dict:
    cols = read_csv(root / SCHROEDER_FILE)
    u, y = cols['V1'], cols['V2']
    n = u.size
    fs = SILVERBOX_FS_HZ
    amp = np.abs(np.fft.rfft(u))
    excited = np.flatnonzero(amp[1:] > 0.1 * amp[1:].max()) + 1
    start = time.perf_counter()
    frd, = local_polynomial_frf([u], y, fs, frequency_min_Hz=1.0, frequency_max_Hz=200.0,
                                input_units=['V'], output_unit='V')
    t_frf = time.perf_counter() - start
    sel = select_order(frd, [(0, 2), (1, 2), (2, 2)], criterion='bic')
    c = sel.chosen
    mode = c.modes[0] if c.modes else None
    return {'file': SCHROEDER_FILE, 'source': SOURCES['silverbox'], 'sample_rate_Hz': fs,
            'n_samples': int(n), 'excited_lines': int(excited.size),
            'excited_band_Hz': [float(excited.min() * fs / n), float(excited.max() * fs / n)],
            'estimator': 'LPM (degree 2, 13 lines, every 13th line), 1-200 Hz',
            'n_frequencies': int(frd.frequency_Hz.size), 'frf_s': t_frf,
            'median_rel_std': float(np.median(frd.std / np.abs(frd.response))),
            'median_coherence': float(np.median(frd.coherence)),
            'order': f'{c.numerator_order}/{c.denominator_order}',
            'resonance_Hz': mode.frequency_Hz if mode else None,
            'resonance_std_Hz': mode.frequency_std_Hz if mode else None,
            'damping_ratio': mode.damping_ratio if mode else None,
            'damping_std': mode.damping_std if mode else None,
            'static_gain': float(np.real(c.response([0.0])[0]))}


# ---------------------------------------------------------------- Silverbox Duffing


def _duffing_kernel():
    import numba

    @numba.njit(cache=True, fastmath=True)
    def run(u, dt, substeps, k, d, k3, gain, out):
        # y'' = gain u(t) - d y' - k y - k3 y^3, u linear between samples (first-order hold)
        y = 0.0
        v = 0.0
        h = dt / substeps
        n = u.shape[0]
        for i in range(n):
            out[i] = y
            u0 = u[i]
            u1 = u[i + 1] if i + 1 < n else u[i]
            for s in range(substeps):
                ua = u0 + (u1 - u0) * (s / substeps)
                um = u0 + (u1 - u0) * ((s + 0.5) / substeps)
                ub = u0 + (u1 - u0) * ((s + 1.0) / substeps)
                a1 = gain * ua - d * v - k * y - k3 * y * y * y
                y2 = y + 0.5 * h * v
                v2 = v + 0.5 * h * a1
                a2 = gain * um - d * v2 - k * y2 - k3 * y2 * y2 * y2
                y3 = y + 0.5 * h * v2
                v3 = v + 0.5 * h * a2
                a3 = gain * um - d * v3 - k * y3 - k3 * y3 * y3 * y3
                y4 = y + h * v3
                v4 = v + h * a3
                a4 = gain * ub - d * v4 - k * y4 - k3 * y4 * y4 * y4
                y = y + h / 6.0 * (v + 2.0 * v2 + 2.0 * v3 + v4)
                v = v + h / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        return out

    return run


def duffing(root: Path, linear: Dict) -> Dict:
    import warnings
    warnings.simplefilter('ignore', RuntimeWarning)     # unstable trial points overflow
    cols = read_csv(root / SNLS_FILE)
    u, y = cols['V1'], cols['V2']
    fs = SILVERBOX_FS_HZ
    dt = 1.0 / fs
    substeps = 4
    run = _duffing_kernel()
    warm = 200

    def simulate(p: Dict[str, float], inputs: np.ndarray) -> np.ndarray:
        out = np.empty(inputs.shape[0])
        run(np.ascontiguousarray(inputs + p['input_offset_V']), dt, substeps, p['k_per_s2'],
            p['d_per_s'], p['k3_per_V2_s2'], p['gain_per_s2'], out)
        return out + p['offset_V']

    est = slice(40650, u.size)
    y_est = y[est]

    def simulate_est(p: Dict[str, float], inputs: np.ndarray) -> np.ndarray:
        out = simulate(p, inputs)
        out[:warm] = y_est[:warm]          # unknown initial state: the first samples are free
        return out

    wn = 2 * np.pi * linear['resonance_Hz']
    zeta = linear['damping_ratio']
    k0 = wn ** 2
    specs = [ParameterSpec('k_per_s2', k0, 0.3 * k0, 3 * k0, True, k0, '1/s^2'),
             ParameterSpec('d_per_s', 2 * zeta * wn, 0.0, 20 * zeta * wn, True,
                           2 * zeta * wn, '1/s'),
             ParameterSpec('k3_per_V2_s2', 0.0, -100 * k0, 100 * k0, True, k0, '1/(V^2 s^2)'),
             ParameterSpec('gain_per_s2', linear['static_gain'] * k0, -10 * k0, 10 * k0, True,
                           abs(linear['static_gain']) * k0, '1/s^2'),
             ParameterSpec('offset_V', float(np.mean(y_est)), -0.1, 0.1, True, 1e-3, 'V'),
             ParameterSpec('input_offset_V', 0.0, -0.1, 0.1, True, 1e-3, 'V')]
    section = DataSection('multisine', u[est], y_est)
    simulate(specs_values(specs), u[:10])      # compile the kernel
    no_input_offset = [s if s.name != 'input_offset_V' else
                       ParameterSpec(s.name, 0.0, free=False) for s in specs]
    rows = []
    for label, method, model in (('with input offset', 'least_squares', specs),
                                 ('with input offset', 'pattern_search', specs),
                                 ('without input offset', 'least_squares', no_input_offset)):
        fit = fit_greybox(simulate_est, [section], model, method=method)
        test = simulate(fit.parameters, u[:40576])[100:40576]
        rms = float(np.sqrt(np.mean((test - y[100:40576]) ** 2)))
        rows.append({'model': label, 'method': method,
                     'evaluations': fit.optimizer_evaluations,
                     'time_s': fit.time_s, 'success': fit.success,
                     'exit_reason': fit.exit_reason,
                     'estimation_fit_percent': float(np.min(fit.sections[0].fit_percent)),
                     'estimation_rms_mV': 1e3 * float(fit.sections[0].rms_error[0]),
                     'test_rms_mV': 1e3 * rms,
                     'parameters': fit.parameters, 'standard_errors': fit.standard_errors})
    lin_specs = [s if s.name not in ('k3_per_V2_s2', 'input_offset_V') else
                 ParameterSpec(s.name, 0.0, free=False) for s in specs]
    lin = fit_greybox(simulate_est, [section], lin_specs)
    lin_rms = float(np.sqrt(np.mean((simulate(lin.parameters, u[:40576])[100:40576]
                                     - y[100:40576]) ** 2)))
    return {'file': SNLS_FILE, 'source': SOURCES['silverbox'], 'sample_rate_Hz': fs,
            'estimation_samples': [40650, int(u.size)], 'test_samples': [100, 40575],
            'rk4_substeps': substeps, 'fits': rows,
            'linear_baseline_test_rms_mV': 1e3 * lin_rms,
            'output_rms_test_mV': 1e3 * float(np.sqrt(np.mean(y[100:40576] ** 2)))}


def specs_values(specs: List[ParameterSpec]) -> Dict[str, float]:
    return {s.name: s.initial for s in specs}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--datasets', required=True, type=Path,
                        help='folder holding f16-gvt/ and silverbox/')
    parser.add_argument('--json', default=str(ROOT / 'bench' / 'results' /
                                              'ident_real_data.json'))
    args = parser.parse_args()
    out = {'machine': {'python': platform.python_version(), 'platform': platform.platform()}}

    out['f16'] = f16(args.datasets)
    print(f'F-16 GVT ({out["f16"]["source"]}): {F16_FILE}, fs {out["f16"]["sample_rate_Hz"]:g} '
          f'Hz, {out["f16"]["periods"]} periods x 8192, first dropped')
    print('\n| channel | order | median rel. std | median rel. fit error | modes 3-15 Hz: '
          'frequency [Hz] (damping ratio) |')
    print('|---|---|---|---|---|')
    for r in out['f16']['channels']:
        modes = '; '.join(f'{m["frequency_Hz"]:.3f} +/- {m["frequency_std_Hz"]:.3f} '
                          f'({m["damping_ratio"]:.4f} +/- {m["damping_std"]:.4f})'
                          for m in r['modes'])
        print(f'| {r["channel"]} | {r["order"]} | {r["median_rel_std"]:.3f} | '
              f'{r["median_rel_fit_error"]:.3f} | {modes} |')

    out['silverbox_frf'] = s = schroeder(args.datasets)
    print(f'\nSilverbox ({s["source"]}): {SCHROEDER_FILE}, {s["excited_lines"]} excited lines '
          f'{s["excited_band_Hz"][0]:.3f}-{s["excited_band_Hz"][1]:.1f} Hz; {s["estimator"]}: '
          f'{s["n_frequencies"]} lines in {s["frf_s"]:.3f} s, median coherence '
          f'{s["median_coherence"]:.4f}, median relative std {s["median_rel_std"]:.4f}; fit '
          f'{s["order"]}: resonance {s["resonance_Hz"]:.3f} +/- '
          f'{s["resonance_std_Hz"]:.3f} Hz, damping {s["damping_ratio"]:.4f} +/- '
          f'{s["damping_std"]:.4f}, static gain {s["static_gain"]:.4f} V/V')

    out['silverbox_duffing'] = d = duffing(args.datasets, s)
    print(f'\nSilverbox Duffing grey-box ({SNLS_FILE}; estimation samples 40650.., test '
          f'arrow 100..40575, output rms {d["output_rms_test_mV"]:.1f} mV; linear model '
          f'baseline test rms {d["linear_baseline_test_rms_mV"]:.2f} mV)')
    print('\n| model | optimiser | evaluations | time [s] | estimation fit % | '
          'estimation rms [mV] | test rms [mV] |')
    print('|---|---|---|---|---|---|---|')
    for r in d['fits']:
        print(f'| {r["model"]} | {r["method"]} | {r["evaluations"]} | {r["time_s"]:.2f} | '
              f'{r["estimation_fit_percent"]:.2f} | {r["estimation_rms_mV"]:.3f} | '
              f'{r["test_rms_mV"]:.3f} |')
    path = Path(args.json)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=2, default=float))
    print(f'\nwrote {path}')


if __name__ == '__main__':
    main()
