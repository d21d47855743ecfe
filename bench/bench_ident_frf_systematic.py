#!/usr/bin/env python3
"""
The FRFs' systematic (type B) part on drawn units: the combined uncertainty's coverage.

Each draw is a unit of the balance type (``offnominal.draw_unit`` with its force constants,
benchmark seeds): its own mechanics, amplifier curves, force constants and a sensor gain drawn
from the stated uncertainty. Its recording is identified twice without the grey-box: with the
file's characteristics (what a user has) and with the unit's own (the reference, including its
sensor). Per FRF, the magnitude scale of the first against the second over the well-coherent
lines (variance-weighted mean ratio) is the error the characteristics cause; it is compared
with the statistical uncertainty of that mean alone and with the combined one (statistical
plus the FRF's reported systematic part): the share of draws inside 1.96 of each.

Usage: ``.venv/bin/python bench/bench_ident_frf_systematic.py [--draws N]``; writes
``bench/results/ident_frf_systematic.json``.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
import json
import math
from pathlib import Path
import time

import numpy as np

from emfc_ros.core.ident.offnominal import (BENCH_SEEDS, draw_unit, record_draw,
                                            with_position_gain)
from emfc_ros.core.ident.pipeline import identify

INPUTS = ('coil_chirp.coil', 'load_changer_chirp.pan')


def one(seed: int) -> dict:
    unit = draw_unit(seed, force_constants=True)
    rec = with_position_gain(record_draw(unit.params, seed, draw_seed=seed), unit.sensor_gain)
    # as a device records it: no force channels (the FRFs take the forces from the currents)
    channels = {k: v for k, v in rec.recording.channels.items()
                if k not in ('coil_force_N', 'load_changer_force_N')}
    rec = replace(rec, recording=replace(rec.recording, channels=channels))
    options = dict(rec.options(), greybox={'enabled': False})
    user = identify(rec.recording, rec.section_table, options)
    # the reference: the unit's own characteristics, its sensor's gain removed
    true_channels = dict(rec.recording.channels)
    true_channels['position_m'] = true_channels['position_m'] / unit.sensor_gain
    truth = replace(rec, recording=replace(rec.recording, channels=true_channels))
    reference = identify(truth.recording, truth.section_table,
                         dict(options, balance=unit.params.to_mapping()))
    ref = {r.name: r for r in reference.frfs}
    row = {'seed': seed, 'factors': unit.factors}
    for r in user.frfs:
        if r.name not in INPUTS:
            continue
        good = ref[r.name]
        band = (good.frd.coherence > 0.99) & (good.frd.frequency_Hz > 5.0)
        ratio = np.abs(r.frd.response[band] / good.frd.response[band])
        rel = r.frd.std[band] / np.abs(r.frd.response[band])
        weights = 1.0 / rel ** 2
        error = float(np.sum(weights * ratio) / np.sum(weights)) - 1.0
        statistical = float(1.0 / math.sqrt(np.sum(weights)))
        systematic = r.systematic.relative
        row[r.name] = {'error': error, 'statistical': statistical, 'systematic': systematic,
                       'z_statistical': error / statistical,
                       'z_combined': error / math.hypot(statistical, systematic),
                       'lines': int(band.sum())}
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument('--draws', type=int, default=20)
    args = ap.parse_args()
    start = time.perf_counter()
    rows = [one(seed) for seed in BENCH_SEEDS[:args.draws]]
    summary = {}
    for name in INPUTS:
        got = [r[name] for r in rows if name in r]
        errors = np.array([g['error'] for g in got])
        summary[name] = {
            'draws': len(got),
            'worst_error_percent': float(100.0 * np.max(np.abs(errors))),
            'median_statistical_percent': float(100.0 * np.median(
                [g['statistical'] for g in got])),
            'systematic_percent': float(100.0 * got[0]['systematic']) if got else None,
            'coverage_95_statistical_only': float(np.mean(
                [abs(g['z_statistical']) <= 1.96 for g in got])),
            'coverage_95_combined': float(np.mean([abs(g['z_combined']) <= 1.96 for g in got])),
        }
    out = {'draws': args.draws, 'seeds': list(BENCH_SEEDS[:args.draws]), 'summary': summary,
           'rows': rows, 'time_s': time.perf_counter() - start}
    for name, s in summary.items():
        print(f'{name}: {s["draws"]} draws, worst error {s["worst_error_percent"]:.2f} %, '
              f'statistical {s["median_statistical_percent"]:.3f} % (median), systematic '
              f'{s["systematic_percent"]:.2f} %; 95 % coverage statistical only '
              f'{100 * s["coverage_95_statistical_only"]:.0f} %, combined '
              f'{100 * s["coverage_95_combined"]:.0f} %')
    path = Path(__file__).resolve().parent / 'results' / 'ident_frf_systematic.json'
    path.parent.mkdir(exist_ok=True)
    path.write_text(json.dumps(out, indent=1, default=float))
    print(f'{path} ({out["time_s"]:.0f} s)')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
