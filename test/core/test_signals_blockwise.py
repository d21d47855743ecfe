"""Block-wise generation equals whole-array generation bit for bit, for every signal type."""

from hypothesis import given, HealthCheck, settings, strategies as st
import numpy as np
import pytest

from emfc_ros.core.signals import (Chirp, Constant, experiment_from_config, GaussianNoise,
                                   Multisine, Prbs, Sine, staircase, Steps, UniformNoise,
                                   Waveform)

FS = 10000.0
N = 12000

FACTORIES = {
    'sine': lambda: Sine(0.3, 123.4, 0.5, FS),
    'chirp_log_repeat': lambda: Chirp(0.01, 5.0, 2000.0, 0.37, FS, 'logarithmic', 'repeat'),
    'chirp_lin_zero': lambda: Chirp(0.2, 2000.0, 5.0, 0.51, FS, 'linear', 'zero'),
    'multisine': lambda: Multisine(0.1, 1000, FS, f_min_Hz=10.0, f_max_Hz=3000.0),
    'multisine_random': lambda: Multisine(0.1, 997, FS, lines=[1, 3, 50], phases='random'),
    'prbs_7': lambda: Prbs(7, 3, -0.1, 0.1, FS),
    'prbs_31': lambda: Prbs(31, 2, -0.1, 0.1, FS),
    'uniform_noise': lambda: UniformNoise(-0.1, 0.2, 5, FS),
    'gaussian_noise': lambda: GaussianNoise(0.0, 0.05, 6, FS),
    'steps': lambda: Steps([0.1, 0.25, 0.9], [0.2, -0.2, 0.0], FS),
    'staircase': lambda: staircase(0.0, 0.1, 5, 0.11, FS, up_and_down=True),
    'constant': lambda: Constant(0.7, FS),
    'waveform_repeat': lambda: Waveform(np.sin(np.arange(777) * 0.1), FS, 'repeat'),
    'waveform_hold': lambda: Waveform(np.cos(np.arange(5000) * 0.01), FS, 'hold'),
}
WHOLE = {}


def whole(name, offset):
    key = (name, offset)
    if key not in WHOLE:
        WHOLE[key] = FACTORIES[name]().samples(np.arange(offset, offset + N, dtype=np.int64))
    return WHOLE[key]


def blocks(signal, offset, sizes):
    out, pos = [], 0
    for size in sizes:
        if pos >= N:
            break
        size = min(size, N - pos)
        out.append(signal.samples(np.arange(offset + pos, offset + pos + size,
                                            dtype=np.int64)))
        pos += size
    if pos < N:
        out.append(signal.samples(np.arange(offset + pos, offset + N, dtype=np.int64)))
    return np.concatenate(out)


SIZES = st.lists(st.integers(min_value=1, max_value=5000), min_size=1, max_size=30)


@pytest.mark.parametrize('name', sorted(FACTORIES))
@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(sizes=SIZES, offset=st.sampled_from([0, 4093, 10 ** 9 + 17]))
def test_blockwise_equals_whole_array(name, sizes, offset):
    got = blocks(FACTORIES[name](), offset, sizes)
    np.testing.assert_array_equal(got, whole(name, offset))
    assert got.dtype == np.float64


def test_samples_keep_shape():
    k = np.arange(12, dtype=np.int64).reshape(3, 4)
    for name, factory in FACTORIES.items():
        signal = factory()
        out = signal.samples(k)
        assert out.shape == (3, 4), name
        np.testing.assert_array_equal(out.ravel(), signal.samples(k.ravel()))


MIXED = {
    'sample_rate_Hz': 10000,
    'limits': {'coil': {'min_V': -0.25, 'max_V': 0.25}},
    'sections': ['one', 'two', 'three'],
    'section': {
        'one': {'duration_s': 0.2049, 'coil': {'gain': 2, 'offset_V': 0.01, 'signals': {
            'chirp': {'type': 'chirp', 'amplitude_V': 0.2, 'f_start_Hz': 5,
                      'f_stop_Hz': 2000, 'sweep_time_s': 0.05},
            'noise': {'type': 'gaussian_noise', 'std_V': 0.01, 'seed': 4}}},
            'load_changer': {'signals': {
                'prbs': {'type': 'prbs', 'order': 9, 'hold_samples': 3, 'low_V': -0.2,
                         'high_V': 0.2}}}},
        'two': {'duration_s': 0.1, 'load_changer': {'signals': {
            'ms': {'type': 'multisine', 'rms_V': 0.1, 'period_samples': 250,
                   'f_min_Hz': 40, 'f_max_Hz': 4000}}}},
        'three': {'duration_s': 0.3, 'coil': {'signals': {
            'steps': {'type': 'staircase', 'start_V': 0, 'step_V': 0.1, 'count': 4,
                      'dwell_s': 0.05},
            'sine': {'type': 'sine', 'amplitude_V': 0.05, 'frequency_Hz': 50},
            'u': {'type': 'uniform_noise', 'low_V': -0.01, 'high_V': 0.01}}}},
    },
}
REF = {}


def mixed():
    if not REF:
        exp = experiment_from_config(MIXED)
        REF['exp'] = exp
        REF['whole'] = exp.block(0, exp.total_samples + 321)
    return REF['exp'], REF['whole']


@settings(max_examples=25, deadline=None)
@given(sizes=st.lists(st.integers(min_value=3, max_value=4000), min_size=1, max_size=40),
       fresh=st.booleans())
def test_experiment_blockwise_equals_whole(sizes, fresh):
    exp, ref = mixed()
    if fresh:           # a new experiment: no cached chunks or tables shared with ref
        exp = experiment_from_config(MIXED)
    total = ref.shape[1]
    assert exp.total_samples == 2049 + 1000 + 3000
    parts, pos, i = [], 0, 0
    while pos < total:
        size = min(sizes[i % len(sizes)], total - pos)
        parts.append(exp.block(pos, size))
        pos += size
        i += 1
    np.testing.assert_array_equal(np.concatenate(parts, axis=1), ref)
