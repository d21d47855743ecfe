"""Waveform files: good CSV and NPY, end modes, and every validation failure."""

import numpy as np
import pytest

from emfc_ros.core.errors import WaveformFileError
from emfc_ros.core.signals import load_waveform, Waveform

FS = 1000.0


def write_csv(path, header, rows):
    path.write_text(header + '\n' + '\n'.join(','.join(str(v) for v in row) for row in rows)
                    + '\n')
    return path


def test_good_csv_with_time_column(tmp_path):
    values = [0.0, 0.1, -0.2, 0.3]
    path = write_csv(tmp_path / 'w.csv', 'sample_index,time_s,coil_V,load_changer_V',
                     [(i, i / FS, v, 2 * v) for i, v in enumerate(values)])
    wave = load_waveform(path, FS, column='load_changer_V')
    np.testing.assert_array_equal(wave.samples(np.arange(6)), [0, 0.2, -0.4, 0.6, 0, 0])


def test_good_csv_single_voltage_column_is_the_default(tmp_path):
    path = write_csv(tmp_path / 'w.csv', 'coil_V', [(1.5,), (2.5,)])
    wave = load_waveform(path, FS, end='hold')
    np.testing.assert_array_equal(wave.samples(np.arange(4)), [1.5, 2.5, 2.5, 2.5])


def test_good_npy_1d_and_2d(tmp_path):
    np.save(tmp_path / 'a.npy', np.array([1.0, 2.0, 3.0]))
    np.save(tmp_path / 'b.npy', np.array([[1.0, 10.0], [2.0, 20.0], [3.0, 30.0]]))
    a = load_waveform(tmp_path / 'a.npy', FS, file_sample_rate_Hz=FS, end='repeat')
    np.testing.assert_array_equal(a.samples(np.arange(7)), [1, 2, 3, 1, 2, 3, 1])
    b = load_waveform(tmp_path / 'b.npy', FS, column=1, file_sample_rate_Hz=FS)
    np.testing.assert_array_equal(b.samples(np.arange(4)), [10, 20, 30, 0])


def test_end_modes_from_array():
    data = np.array([1.0, -1.0])
    k = np.arange(5)
    np.testing.assert_array_equal(Waveform(data, FS, 'zero').samples(k), [1, -1, 0, 0, 0])
    np.testing.assert_array_equal(Waveform(data, FS, 'hold').samples(k), [1, -1, -1, -1, -1])
    np.testing.assert_array_equal(Waveform(data, FS, 'repeat').samples(k), [1, -1, 1, -1, 1])


def _bad_files(tmp_path):
    rows = [(i / FS, 0.1 * i) for i in range(5)]
    cases = {
        'wrong rate': (write_csv(tmp_path / 'rate.csv', 'time_s,coil_V',
                                 [(i / 500.0, 0.0) for i in range(5)]), {}, 'sample rate'),
        'uneven time': (write_csv(tmp_path / 'uneven.csv', 'time_s,coil_V',
                                  rows[:3] + [(0.0035, 0.0)]), {}, 'rows 3-4'),
        'nan': (write_csv(tmp_path / 'nan.csv', 'time_s,coil_V',
                          rows[:2] + [(0.002, 'nan')] + rows[3:]), {}, 'row 3'),
        'inf': (write_csv(tmp_path / 'inf.csv', 'coil_V', [(0.0,), ('inf',)]), {},
                'not finite'),
        'text cell': (write_csv(tmp_path / 'text.csv', 'coil_V', [(0.0,), ('abc',)]), {},
                      "'abc' is not a number"),
        'units': (write_csv(tmp_path / 'units.csv', 'coil_mV', [(0.0,), (1.0,)]),
                  dict(column='coil_mV'), 'unit suffix _V'),
        'no unit': (write_csv(tmp_path / 'nounit.csv', 'coil', [(0.0,), (1.0,)]), {},
                    'no unit suffix'),
        'ambiguous': (write_csv(tmp_path / 'two.csv', 'a_V,b_V', [(0, 0), (1, 1)]), {},
                      'choose one'),
        'missing column': (write_csv(tmp_path / 'col.csv', 'a_V', [(0,), (1,)]),
                           dict(column='b_V'), "no column 'b_V'"),
        'ragged': (write_csv(tmp_path / 'ragged.csv', 'a_V,time_s', [(0, 0), (1,)]), {},
                   'row 2'),
        'too short': (write_csv(tmp_path / 'short.csv', 'coil_V', [(1.0,)]), {},
                      'at least 2'),
        'header only': (write_csv(tmp_path / 'header.csv', 'coil_V', []), {}, 'no data'),
        'bad path': (tmp_path / 'missing.csv', {}, 'cannot read'),
        'extension': (write_csv(tmp_path / 'w.txt', 'coil_V', [(0,), (1,)]), {},
                      'unknown waveform file type'),
    }
    (tmp_path / 'empty.csv').write_text('')
    cases['empty'] = (tmp_path / 'empty.csv', {}, 'empty file')
    np.save(tmp_path / 'nan.npy', np.array([0.0, np.nan, 1.0]))
    cases['npy nan'] = (tmp_path / 'nan.npy', dict(file_sample_rate_Hz=FS), 'row 2')
    np.save(tmp_path / 'ok.npy', np.zeros(4))
    cases['npy rate'] = (tmp_path / 'ok.npy', dict(file_sample_rate_Hz=2 * FS), 'sample rate')
    cases['npy no rate'] = (tmp_path / 'ok.npy', {}, 'file_sample_rate_Hz')
    np.save(tmp_path / 'two.npy', np.zeros((4, 2)))
    cases['npy column'] = (tmp_path / 'two.npy', dict(file_sample_rate_Hz=FS, column=2),
                           'out of range')
    np.save(tmp_path / 'empty.npy', np.zeros(0))
    cases['npy empty'] = (tmp_path / 'empty.npy', dict(file_sample_rate_Hz=FS), 'at least 2')
    (tmp_path / 'garbage.npy').write_bytes(b'not an npy file')
    cases['npy garbage'] = (tmp_path / 'garbage.npy', dict(file_sample_rate_Hz=FS),
                            'cannot read')
    return cases


CASES = ['wrong rate', 'uneven time', 'nan', 'inf', 'text cell', 'units', 'no unit',
         'ambiguous', 'missing column', 'ragged', 'too short', 'header only', 'bad path',
         'extension', 'empty', 'npy nan', 'npy rate', 'npy no rate', 'npy column', 'npy empty',
         'npy garbage']


@pytest.mark.parametrize('case', CASES)
def test_validation_failures_name_file_and_problem(tmp_path, case):
    path, kwargs, problem = _bad_files(tmp_path)[case]
    with pytest.raises(WaveformFileError) as info:
        load_waveform(path, FS, **kwargs)
    message = str(info.value)
    assert str(path) in message
    assert problem in message
