"""
The experiment runner on the ``daqmx`` back-end, end to end, as the README shows it.

``emfc-experiment config/experiment_daqmx_emulator.yaml`` runs as a user types it (a separate
process): the runner starts ``emfc-daqmx-emulator`` (a process of its own, gRPC on loopback),
the daq_bridge node talks to it through NI's own ``nidaqmx`` client, the bag is read back
with the independent ``mcap`` reader, and the identification is compared with the simulator
target's on the same experiment, parameter by parameter, within the reported uncertainties.
"""

import json
from pathlib import Path
import subprocess

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from test_experiment_bridge import _run, _write_plan
import yaml

from emfc_ros.core.bag import read_streams
from emfc_ros.core.paths import config_file
from emfc_ros.core.run_plan import load_plan
from emfc_ros.core.signals import experiment_from_config
import readme_lines
import ros_harness
from ros_harness import scaled

REPO = Path(__file__).resolve().parents[2]
DAC_LSB_V = 20.0 / 65536
RUN_TIMEOUT_S = scaled(240)
LINE = 'emfc-experiment config/experiment_daqmx_emulator.yaml'


def _messages(bag: Path, topic: str):
    out = []
    for path in sorted(bag.glob('*.mcap')):
        with open(path, 'rb') as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            for _, _, _, decoded in reader.iter_decoded_messages(topics=[topic]):
                out.append(decoded)
    return out


def _blocks(bag: Path, topic: str):
    blocks = []
    for msg in _messages(bag, topic):
        dims = {d.label: d for d in msg.layout.dim}
        channels, samples = dims['channel'].size, dims['sample'].size
        offset = msg.layout.data_offset
        blocks.append((int(msg.data[0]), np.asarray(
            msg.data[offset:offset + channels * samples]).reshape(channels, samples)))
    return blocks


@pytest.mark.slow
def test_the_daqmx_plan_records_and_identifies_as_the_simulator_target_does(tmp_path):
    argv = readme_lines.readme_argv(LINE)
    (tmp_path / 'config').symlink_to(REPO / 'config')
    result = subprocess.run(argv, capture_output=True, text=True, timeout=RUN_TIMEOUT_S,
                            env=ros_harness.child_environment(), cwd=tmp_path)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert 'emulated NI-DAQmx device (emfc-daqmx-emulator, its own process) on 127.0.0.1:' \
        in result.stdout
    folders = list((tmp_path / 'out').iterdir())
    assert len(folders) == 1
    out = folders[0]
    bag = out / 'bag'

    plan = load_plan(config_file('experiment_daqmx_emulator.yaml'))
    experiment = experiment_from_config(plan.experiment)
    total = experiment.total_samples

    descriptions = [json.loads(m.data) for m in
                    _messages(bag, '/emfc/measurements/description')]
    extra = descriptions[-1]['extra']
    assert extra['backend'] == 'daqmx' and extra['faults'] == []
    assert extra['daqmx']['hardware_watchdog'] is True
    assert extra['daqmx']['ao_sample_clock'] == '/Dev1/ai/SampleClock'
    assert extra['daqmx']['connection'].startswith('grpc 127.0.0.1:')
    offset = extra['excitation_offset_samples']

    # The device clock from sample 0, contiguous, no gap, the whole experiment.
    blocks = _blocks(bag, '/emfc/measurements')
    firsts = [f for f, _ in blocks]
    assert firsts[0] == 0
    assert all(b - a == d.shape[1] for (a, d), b in zip(blocks, firsts[1:]))
    measured = np.concatenate([d for _, d in blocks], axis=1)
    assert measured.shape[1] >= offset + total
    excitation = np.concatenate([d for _, d in _blocks(bag, '/emfc/excitation')], axis=1)
    np.testing.assert_array_equal(excitation, experiment.block(0, total))
    # ao0 looped back on ai3: excitation sample k at device sample offset + k, one tick
    names = read_streams(bag)['/emfc/measurements'].channel_names
    applied = measured[names.index('coil_setpoint_V')]
    np.testing.assert_allclose(applied[offset:offset + total], excitation[0], atol=DAC_LSB_V)
    assert np.max(np.abs(applied[offset + 1:offset + total] - excitation[0, :-1])) > \
        100 * DAC_LSB_V

    daqmx = yaml.safe_load((out / 'identification' / 'results.yaml').read_text())
    assert daqmx['status']['success'] is True

    # The simulator target on the same experiment and identification options.
    run = yaml.safe_load(config_file('experiment_daqmx_emulator.yaml').read_text())['run']
    sim_plan = {'run': {
        'name': 'simulator', 'target': 'simulator', 'namespace': '/emfc',
        'experiment_files': [str(config_file('experiment_daqmx_emulator.yaml'))],
        'block_size': run['block_size'], 'timeout_s': 120.0,
        'simulator': {'balance_file': str(config_file('balance_default.yaml')),
                      'load_mass_kg': 'balance', 'load_changer_coupled': True, 'seed': 0},
        'identification': run['identification']}}
    sim_result = _run([str(_write_plan(tmp_path, 'sim.yaml', sim_plan)), '-o',
                       str(tmp_path / 'sim')], cwd=tmp_path)
    assert sim_result.returncode == 0, sim_result.stdout[-3000:] + sim_result.stderr[-3000:]
    sim = yaml.safe_load((tmp_path / 'sim' / 'identification' / 'results.yaml').read_text())

    # Every identified grey-box parameter agrees within the reported uncertainties (k = 2,
    # both runs' combined standard uncertainties).
    pa, pb = daqmx['greybox']['parameters'], sim['greybox']['parameters']
    assert set(pa) == set(pb) and len(pa) >= 5
    for name in pa:
        a, b = pa[name], pb[name]
        u = np.hypot(a['combined_standard_uncertainty'], b['combined_standard_uncertainty'])
        assert abs(a['value'] - b['value']) <= 2.0 * u, (name, a, b)
    # and the static coil amplifier, coefficient by coefficient, within k = 2 of the two
    # standard errors
    ca = daqmx['static_characteristics']['coil_amplifier']['coefficients_ascending']
    cb = sim['static_characteristics']['coil_amplifier']['coefficients_ascending']
    for a, b in zip(ca, cb):
        u = np.hypot(a['standard_error'], b['standard_error'])
        assert abs(a['value'] - b['value']) <= 2.0 * u, (a, b)
    # The FRFs agree where they are well excited (below 200 Hz, at the 350 Hz resonance),
    # within 4 of the two runs' statistical magnitude uncertainties (the same sensor and force
    # constants: no systematic difference), and so do their transfer-function resonances.
    # Their systematic parts differ as the recordings do: the device's has no force channel
    # (the force from the measured current and the force constant), the simulator's has.
    frfs = {r['name']: r for r in sim['frequency_responses']}
    compared = 0
    for ra in daqmx['frequency_responses']:
        rb = frfs[ra['name']]
        assert 'current_monitor_gain_relative' in ra['systematic_inputs']
        assert set(rb['systematic_inputs']) == {'sensor_gain_relative', 'adc_gain_relative'}
        rows = {row['frequency_Hz']: row for row in rb.get('selected_frequencies') or []}
        for row in ra.get('selected_frequencies') or []:
            f, other = row['frequency_Hz'], rows[row['frequency_Hz']]
            if f <= 200.0 or 340.0 <= f <= 360.0:
                u = np.hypot(row['magnitude_std_m_per_N'], other['magnitude_std_m_per_N'])
                assert abs(row['magnitude_m_per_N'] - other['magnitude_m_per_N']) <= 4.0 * u, \
                    (ra['name'], f, row, other)
                compared += 1
        if ra.get('transfer_function') and rb.get('transfer_function'):
            ma = max(ra['transfer_function']['resonances'], key=lambda m: m['frequency_Hz'])
            mb = max(rb['transfer_function']['resonances'], key=lambda m: m['frequency_Hz'])
            u = np.hypot(ma['frequency_std_Hz'], mb['frequency_std_Hz'])
            assert abs(ma['frequency_Hz'] - mb['frequency_Hz']) <= 4.0 * u, (ra['name'], ma, mb)
    assert compared >= 5            # (6 on the shipped plan: not vacuous)
