"""
``emfc-identify BAG`` as a user types it, on bags of a drawn balance: good and broken on purpose.

The bags are written with the project's bag writer (``test/ident_bags.py``) from off-nominal
recordings (:mod:`emfc_ros.core.ident.offnominal`, a test seed, 3 s sections); the measurement
description carries the pan load as a plant simulator publishes it. A failed fit exits with 1,
its report written and its headline saying FAILED.
"""

from pathlib import Path
import shutil
import subprocess
import sys

import pytest
import yaml

from emfc_ros.core.bag import read_streams
from emfc_ros.core.ident.balance_experiment import time_scaled_mapping
from emfc_ros.core.ident.errors import IdentificationError
from emfc_ros.core.ident.from_bag import experiment_sections
from emfc_ros.core.ident.offnominal import (draw_balance, record_draw, TEST_SEEDS,
                                            with_noise_position, with_position_gain)
from emfc_ros.core.paths import config_file
from emfc_ros.core.signals import experiment_from_config, find_experiment_mapping
import ident_bags
from ros_harness import scaled

SEED = TEST_SEEDS[3]


def _cli() -> str:
    return shutil.which('emfc-identify') or str(Path(sys.executable).parent / 'emfc-identify')


@pytest.fixture(scope='module')
def record():
    doc = yaml.safe_load(config_file('identification_trajectory.yaml').read_text())
    exp = experiment_from_config(time_scaled_mapping(find_experiment_mapping(doc), 0.3))
    return record_draw(draw_balance(SEED), SEED, experiment=exp, draw_seed=SEED)


def bag_of(record, folder: Path, **kwargs) -> Path:
    rec = record.recording
    return ident_bags.write_experiment_bag(folder / 'bag', rec.channels, rec.sample_rate_Hz,
                                           record.section_table,
                                           extra={'load_mass_kg': record.known_load_mass_kg,
                                                  'load_changer_coupled':
                                                      record.load_changer_coupled,
                                                  'time_mode': 'simulated'}, **kwargs)


def identify(bag: Path, out: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([_cli(), str(bag), '-o', str(out), *extra], capture_output=True,
                          text=True, timeout=scaled(600))


@pytest.mark.slow
def test_an_intact_bag_is_identified(record, tmp_path):
    done = identify(bag_of(record, tmp_path), tmp_path / 'out')
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    results = yaml.safe_load((tmp_path / 'out' / 'results.yaml').read_text())
    assert results['status']['success'] is True
    assert results['configuration']['load_mass_kg'] == record.known_load_mass_kg
    assert results['configuration']['source'].startswith(
        'load_mass_kg from measurement description (extra)')
    # the figures, drawn by the command's plot workers, all there and none failed
    names = {p.name for p in (tmp_path / 'out').glob('*.png')}
    assert {'bode_coil_chirp.coil.png', 'coherence_coil_chirp.coil.png', 'time_coil_chirp.png',
            'resid_coil_chirp.png', 'pole_zero.png'} <= names, names
    summary = (tmp_path / 'out' / 'summary.md').read_text()
    assert 'plot failed' not in summary
    assert all(name in summary for name in names)


def test_the_excitation_description_alone_is_enough(record, tmp_path):
    """
    A recording of the measurements with the excitation's description but not its blocks.

    The measurements hold the applied setpoints; the description carries the sections (the
    message asked to record the description, which was recorded, before issue 27). Without
    the description the message says it was not recorded.
    """
    bag = bag_of(record, tmp_path / 'no_blocks', excitation_blocks=False)
    sections = experiment_sections(bag, read_streams(bag), '/emfc')
    assert [s['name'] for s in sections] == [s[0] for s in record.section_table]
    bare = bag_of(record, tmp_path / 'nothing', excitation_blocks=False,
                  excitation_description=False)
    with pytest.raises(IdentificationError,
                       match='/emfc/excitation/description was not recorded'):
        experiment_sections(bare, read_streams(bare), '/emfc')
    # emfc-identify on it: exit 1, and the report says why (every exit writes one).
    done = identify(bare, tmp_path / 'out')
    assert done.returncode == 1, done.stdout + done.stderr
    assert 'was not recorded' in done.stderr
    summary = (tmp_path / 'out' / 'summary.md').read_text()
    assert '**Identification FAILED**: /emfc/excitation/description was not recorded' in summary
    results = yaml.safe_load((tmp_path / 'out' / 'results.yaml').read_text())
    assert results['status']['success'] is False and 'was not recorded' in \
        results['status']['failures'][0]


@pytest.mark.slow
@pytest.mark.parametrize('broken', ['wrong_pan_load', 'position_gain', 'noise_position'])
def test_a_failed_fit_exits_1_with_its_report(record, tmp_path, broken):
    args = []
    if broken == 'wrong_pan_load':
        # told twice the real load: the identified mass matrix contradicts it
        bag = bag_of(record, tmp_path)
        args = ['--load-mass-kg', repr(2.0 * record.known_load_mass_kg)]
    elif broken == 'position_gain':
        # 25 % off, 12 times its stated 2 %: the mass check names it (10 % is named on 14
        # of the first 20 benchmark draws, the rest report c1 4.3 combined sigmas off)
        bag = bag_of(with_position_gain(record, 1.25), tmp_path)
    else:
        bag = bag_of(with_noise_position(record, seed=SEED), tmp_path)
    done = identify(bag, tmp_path / 'out', *args)
    assert done.returncode == 1, (broken, done.stdout[-3000:] + done.stderr[-3000:])
    assert 'the identification FAILED' in done.stderr
    results = yaml.safe_load((tmp_path / 'out' / 'results.yaml').read_text())
    assert results['status']['success'] is False and results['status']['failures']
    summary = (tmp_path / 'out' / 'summary.md').read_text()
    assert '**Identification FAILED**' in summary
    if broken == 'wrong_pan_load':
        assert results['configuration']['source'] == 'load_mass_kg from options; ' \
            'load_changer_coupled from measurement description (extra)'
        assert any('mass matrix' in f for f in results['status']['failures'])
