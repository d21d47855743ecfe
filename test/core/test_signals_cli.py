"""emfc-generate: CSV and NPY output, summaries, and exit code 2 on bad input."""

from pathlib import Path

import numpy as np
import yaml

from emfc_ros.cli.generate import main
from emfc_ros.core.signals import load_experiment_file, load_waveform

SHIPPED = Path(__file__).resolve().parents[2] / 'config' / 'identification_trajectory.yaml'
CONFIG = {'experiment': {
    'sample_rate_Hz': 1000.0,
    'sections': ['a', 'b'],
    'section': {
        'a': {'duration_s': 0.5, 'coil': {'signals': {
            's': {'type': 'sine', 'amplitude_V': 0.5, 'frequency_Hz': 10.0}}}},
        'b': {'duration_s': 0.25, 'load_changer': {'offset_V': 0.1, 'signals': {
            'p': {'type': 'prbs', 'order': 5, 'low_V': -0.2, 'high_V': 0.2}}}},
    }}}


def write_config(tmp_path, cfg=CONFIG):
    path = tmp_path / 'exp.yaml'
    path.write_text(yaml.safe_dump(cfg))
    return path


def test_csv_header_rows_and_values(tmp_path, capsys):
    config = write_config(tmp_path)
    out = tmp_path / 'out.csv'
    assert main([str(config), '-o', str(out)]) == 0
    lines = out.read_text().splitlines()
    assert lines[0] == 'sample_index,time_s,coil_V,load_changer_V'
    assert len(lines) == 1 + 750
    table = np.loadtxt(out, delimiter=',', skiprows=1)
    exp = load_experiment_file(config)
    np.testing.assert_array_equal(table[:, 0], np.arange(750))
    np.testing.assert_allclose(table[:, 1], np.arange(750) / 1000.0, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(table[:, 2:].T, exp.block(0, 750))   # %.17g round-trips
    printed = capsys.readouterr().out
    assert 'section 1/2 a' in printed and 'section 2/2 b' in printed
    # the CSV is a valid waveform file (units, time spacing)
    wave = load_waveform(out, 1000.0, column='coil_V')
    np.testing.assert_array_equal(wave.data_V, exp.block(0, 750)[0])


def test_range_and_npy_of_the_shipped_trajectory(tmp_path, capsys):
    out = tmp_path / 'out.npy'
    assert main([str(SHIPPED), '-o', str(out), '--first-sample', '99500',
                 '--samples', '1000']) == 0
    data = np.load(out)
    assert data.shape == (2, 1000)
    np.testing.assert_array_equal(data, load_experiment_file(SHIPPED).block(99500, 1000))
    printed = capsys.readouterr().out
    assert 'coil_chirp' in printed and 'load_changer_chirp' in printed
    assert '(2, 1000)' in printed


def test_past_the_end_rows(tmp_path):
    out = tmp_path / 'out.csv'
    assert main([str(write_config(tmp_path)), '-o', str(out), '--first-sample', '740',
                 '--samples', '20']) == 0
    table = np.loadtxt(out, delimiter=',', skiprows=1)
    assert table.shape == (20, 4)
    np.testing.assert_array_equal(table[10:, 2:], 0.0)


def test_bad_config_exits_2_without_traceback(tmp_path, capsys):
    cfg = yaml.safe_load(yaml.safe_dump(CONFIG))
    cfg['experiment']['section']['a']['coil']['signals']['s']['frequency_Hz'] = 900.0
    out = tmp_path / 'out.csv'
    assert main([str(write_config(tmp_path, cfg)), '-o', str(out)]) == 2
    err = capsys.readouterr().err
    assert 'experiment.section.a.coil.signals.s.frequency_Hz' in err
    assert 'Traceback' not in err
    assert not out.exists()


def test_usage_errors_exit_2(tmp_path, capsys):
    config = str(write_config(tmp_path))
    assert main([config, '-o', str(tmp_path / 'out.txt')]) == 2
    assert main([config, '-o', str(tmp_path / 'o.csv'), '--first-sample', '-1']) == 2
    assert main([config, '-o', str(tmp_path / 'o.csv'), '--samples', '-1']) == 2
    assert main([str(tmp_path / 'missing.yaml'), '-o', str(tmp_path / 'o.csv')]) == 2
    assert main([config]) == 2                    # argparse: -o is required
    err = capsys.readouterr().err
    assert 'Traceback' not in err and 'missing.yaml' in err
