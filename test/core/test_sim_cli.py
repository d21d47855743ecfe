"""The offline commands emfc-model-summary and emfc-simulate."""

import json

import numpy as np
import pytest
import yaml

from emfc_ros.cli import model_summary, simulate
from emfc_ros.core.model import BalanceParameters
from emfc_ros.core.sim import Simulator

FS_HZ = 20000.0


def _summary(capsys, *argv):
    assert model_summary.main(list(argv)) == 0
    return yaml.safe_load(capsys.readouterr().out)


def test_model_summary_prints_the_notes_numbers(capsys):
    data = _summary(capsys)
    assert data['configuration']['pan_mass_kg'] == pytest.approx(0.060)
    poles = [p['frequency_Hz'] for p in data['poles']]
    assert poles == pytest.approx([3.78, 410.0], abs=0.01)
    assert data['poles'][0]['damping_ratio'] == pytest.approx(0.050, abs=5e-4)
    assert data['zeros']['coil'][0]['frequency_Hz'] == pytest.approx(353.85, abs=0.01)
    pan = sorted(z['frequency_Hz'] for z in data['zeros']['pan'])
    assert pan == pytest.approx([-1100.2, 1190.9], abs=0.1)
    gains = data['static_gains']
    assert gains['coil_dB_re_1_m_per_N'] == pytest.approx(-21.83, abs=0.01)
    assert gains['pan_dB_re_1_m_per_N'] == pytest.approx(-39.33, abs=0.01)
    # setpoint to sensor: 5e4 V/m * 0.081 m/N * 21.69 N/A * 0.00999 A/V, plus 0.75 % from the
    # motor coefficient's slope (12 N/(A m) at 7.7 mA: a negative stiffness)
    amp_slope = 0.010 - 2 * 6.964e-6 * 0.7682
    assert gains['coil_setpoint_to_sensor_V_per_V'] == pytest.approx(
        5e4 * 0.081043 * 21.692 * amp_slope / (1.0 - 0.081043 * 12.0 * 0.0076857), rel=1e-4)
    assert gains['load_changer_setpoint_to_sensor_V_per_V'] < 0.0
    op = data['operating_point']
    assert op['position_m'] == 0.0
    assert op['coil_force_N'] == pytest.approx(0.1667, abs=1e-4)


def test_model_summary_for_a_load_and_the_coupled_load_changer(capsys, tmp_path):
    data = _summary(capsys, '--load-mass-kg', '0.1')
    assert data['poles'][1]['frequency_Hz'] == pytest.approx(362.5, abs=0.05)
    data = _summary(capsys, '--load-changer-coupled', '--config', 'config/balance_default.yaml')
    assert data['configuration']['pan_mass_kg'] == pytest.approx(0.085)
    assert data['poles'][1]['frequency_Hz'] == pytest.approx(395.6, abs=0.05)


def test_model_summary_errors_exit_2(capsys, tmp_path):
    assert model_summary.main(['--config', str(tmp_path / 'missing.yaml')]) == 2
    assert 'missing.yaml' in capsys.readouterr().err
    bad = tmp_path / 'bad.yaml'
    bad.write_text('balance:\n  mechanics: {l1_m: -1.0}\n')
    assert model_summary.main(['--config', str(bad)]) == 2
    assert 'balance.' in capsys.readouterr().err
    assert model_summary.main(['--load-mass-kg', '-1']) == 2
    assert 'load_mass_kg' in capsys.readouterr().err


def _write_csv(path, u, rate_Hz=FS_HZ, first=0):
    k = np.arange(first, first + u.shape[1])
    with open(path, 'w') as stream:
        stream.write('sample_index,time_s,coil_V,load_changer_V\n')
        np.savetxt(stream, np.column_stack([k, k / rate_Hz, u.T]), delimiter=',',
                   fmt=['%d', '%.12f', '%.17g', '%.17g'])


def _excitation(n=400):
    u = np.zeros((2, n))
    u[0] = 1e-3 * np.sin(np.arange(n) * 0.05)
    u[1, n // 2:] = 0.01
    return u


def test_simulate_csv_matches_the_simulator(tmp_path, capsys):
    u = _excitation()
    src, dst = tmp_path / 'exc.csv', tmp_path / 'out.csv'
    _write_csv(src, u, first=100)
    assert simulate.main([str(src), '-o', str(dst), '--seed', '4',
                          '--add-hold-setpoints']) == 0
    assert '20000 Hz' in capsys.readouterr().out
    with open(dst) as stream:
        header = stream.readline().strip().split(',')
    table = np.loadtxt(dst, delimiter=',', skiprows=1)
    sim = Simulator(BalanceParameters(), FS_HZ, 4)
    expected = sim.step_block(u + sim.hold_setpoints_V[:, None])
    assert header == ['sample_index', 'time_s'] + list(sim.channel_names)
    np.testing.assert_array_equal(table[:, 0], np.arange(100, 500))
    np.testing.assert_allclose(table[:, 1], np.arange(100, 500) / FS_HZ)
    np.testing.assert_array_equal(table[:, 2:], expected.T)   # %.17g round-trips float64


def test_simulate_npy_with_sidecar_and_options(tmp_path):
    u = _excitation()
    src, dst = tmp_path / 'exc.npy', tmp_path / 'out.npy'
    np.save(src, u.T + 0.768)
    args = [str(src), '-o', str(dst), '--sample-rate-Hz', '10000', '--no-noise',
            '--no-quantisation', '--load-mass-kg', '0.0', '--hold', 'foh']
    assert simulate.main(args) == 0
    data = np.load(dst)
    meta = json.loads((tmp_path / 'out.json').read_text())
    sim = Simulator(BalanceParameters(), 10000.0, 0, noise=False, quantisation=False, hold='foh')
    assert meta['columns'] == ['sample_index', 'time_s'] + list(sim.channel_names)
    assert meta['units'][2:] == list(sim.channel_units)
    assert meta['sample_rate_Hz'] == 10000.0 and meta['noise'] is False
    assert data.shape == (400, 13)
    np.testing.assert_array_equal(data[:, 2:], sim.step_block(u + 0.768).T)
    # the channel-major layout of emfc-generate is accepted too
    np.save(src, u + 0.768)
    assert simulate.main(args) == 0
    np.testing.assert_array_equal(np.load(dst), data)


@pytest.mark.parametrize('content, message', [
    ('coil_V\n1.0\n', 'missing'),
    ('coil_V,load_changer_V\n1.0,nan\n', 'finite'),
    ('coil_V,load_changer_V\n1.0,abc\n', 'cannot read'),
    ('coil_V,load_changer_V\n', 'no samples'),
])
def test_simulate_bad_csv_exits_2(tmp_path, capsys, content, message):
    src = tmp_path / 'exc.csv'
    src.write_text(content)
    assert simulate.main([str(src), '-o', str(tmp_path / 'out.csv')]) == 2
    err = capsys.readouterr().err
    assert err.startswith('emfc-simulate: error:') and message in err
    assert 'Traceback' not in err
    assert not (tmp_path / 'out.csv').exists()


def test_simulate_other_errors_exit_2(tmp_path, capsys):
    src = tmp_path / 'exc.npy'
    np.save(src, np.zeros((5, 3)))
    assert simulate.main([str(src), '-o', str(tmp_path / 'o.npy')]) == 2
    assert 'shape' in capsys.readouterr().err
    assert simulate.main([str(tmp_path / 'none.csv'), '-o', str(tmp_path / 'o.csv')]) == 2
    assert 'none.csv' in capsys.readouterr().err
    np.save(src, np.zeros((5, 2)))
    assert simulate.main([str(src), '-o', str(tmp_path / 'o.txt')]) == 2
    assert '.csv or .npy' in capsys.readouterr().err
    assert simulate.main([str(src), '-o', str(tmp_path / 'o.npy'), '--seed', '-3']) == 2
    assert 'seed' in capsys.readouterr().err
    assert simulate.main([str(src)]) == 2      # argparse: -o is required
