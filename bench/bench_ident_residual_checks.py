#!/usr/bin/env python3
"""
False-alarm rate of the grey-box's residual checks on right models, and what they catch.

Right models: drawn balances (benchmark seeds, each with benchmark noise seeds), the shipped
trajectory identified with the default options; the data come from the same model class the
grey-box fits, so every warning of a residual check is a false alarm. Per check (whiteness,
input correlation, coherence) the fraction of identifications it warned on, by the verdict's
rule (``balance_verdict.RESIDUAL_TEST_ALPHA`` over the sections, Bonferroni) and, for the two
correlation tests, by the rule before issue 28 (fewer than 80 % of the lags inside the 99 %
band), measured on the same fits (the same-run baseline). Then records with an unmodelled
mode (``offnominal.with_extra_mode``) at random frequencies: how often each check names it.

Usage: ``.venv/bin/python bench/bench_ident_residual_checks.py [--draws 100] [--modes 20]``;
writes ``bench/results/ident_residual_checks.json``. Target (issue 28): at most 5 % false
alarms per check over 100 draws.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from emfc_ros.core.ident.balance_verdict import RESIDUAL_TEST_ALPHA
from emfc_ros.core.ident.offnominal import (BENCH_NOISE_SEEDS, BENCH_SEEDS, default_experiment,
                                            draw_balance, record_draw, with_extra_mode)
from emfc_ros.core.ident.pipeline import identify


def checks(res) -> dict:
    """Which check would warn, by the new rule and the old one."""
    sections = [s for s in res.greybox.fit.sections
                if s.residual_tested.startswith('noise-weighted')]
    level = RESIDUAL_TEST_ALPHA / max(len(sections), 1)
    return {
        'whiteness': any(s.whiteness_p_value < level for s in sections),
        'input_correlation': any(s.input_correlation_p_value < level for s in sections),
        'coherence': any(s.coherence is not None and s.coherence.p_value < level
                         for s in sections),
        'whiteness_old_rule': any(s.whiteness_fraction < 0.8 for s in sections),
        'input_correlation_old_rule': any(s.input_correlation_fraction < 0.8
                                          for s in sections),
        'verdict_warned': any('residual' in w for w in res.warnings),
        'peak_Hz': [s.coherence.frequency_Hz for s in sections
                    if s.coherence is not None and s.coherence.p_value < level],
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument('--draws', type=int, default=100)
    ap.add_argument('--modes', type=int, default=20)
    args = ap.parse_args()
    exp = default_experiment()
    pairs = [(BENCH_SEEDS[i % len(BENCH_SEEDS)], BENCH_NOISE_SEEDS[i])
             for i in range(args.draws)]
    right = []
    for draw_seed, noise_seed in pairs:
        rec = record_draw(draw_balance(draw_seed), noise_seed, experiment=exp,
                          draw_seed=draw_seed)
        res = identify(rec.recording, rec.section_table, rec.options())
        row = dict(checks(res), draw_seed=draw_seed, noise_seed=noise_seed,
                   success=res.success)
        right.append(row)
        print(f'right {draw_seed}/{noise_seed}: success {res.success} ' + ' '.join(
            f'{k}={int(v)}' for k, v in row.items() if isinstance(v, bool)), flush=True)
    rng = np.random.default_rng(28402)
    broken = []
    for i in range(args.modes):
        draw_seed = BENCH_SEEDS[i % len(BENCH_SEEDS)]
        rec = record_draw(draw_balance(draw_seed), BENCH_NOISE_SEEDS[-1 - i], experiment=exp,
                          draw_seed=draw_seed)
        f = float(rng.uniform(50.0, 300.0))
        rec = with_extra_mode(rec, f, 0.02, 0.01)
        res = identify(rec.recording, rec.section_table, rec.options())
        row = dict(checks(res), draw_seed=draw_seed, mode_Hz=f, success=res.success)
        broken.append(row)
        print(f'extra mode {f:.0f} Hz on {draw_seed}: ' + ' '.join(
            f'{k}={int(v)}' for k, v in row.items() if isinstance(v, bool))
            + f' peaks {[round(p) for p in row["peak_Hz"]]}', flush=True)
    keys = ('whiteness', 'input_correlation', 'coherence', 'whiteness_old_rule',
            'input_correlation_old_rule', 'verdict_warned')
    summary = {
        'right_models': len(right),
        'false_alarm_rate': {k: float(np.mean([r[k] for r in right])) for k in keys},
        'extra_mode_records': len(broken),
        'detection_rate': {k: float(np.mean([r[k] for r in broken])) for k in keys}
        if broken else {},
        'peak_within_25_Hz': float(np.mean([
            bool(r['peak_Hz']) and all(abs(p - r['mode_Hz']) < 25.0 for p in r['peak_Hz'])
            for r in broken])) if broken else None,
    }
    print(json.dumps(summary, indent=1))
    out = Path(__file__).resolve().parent / 'results'
    out.mkdir(exist_ok=True)
    (out / 'ident_residual_checks.json').write_text(json.dumps(
        {'summary': summary, 'right': right, 'extra_mode': broken}, indent=1))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
