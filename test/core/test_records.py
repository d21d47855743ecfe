"""The shared check of records on one sample clock."""

import numpy as np
import pytest

from emfc_ros.core.ident.errors import IdentificationError
from emfc_ros.core.records import same_clock_records


def test_records_come_back_as_contiguous_float64():
    strided = np.arange(10)[::2]
    a, b = same_clock_records(('a', 'b'), (strided, [1.0, 2.0, 3.0, 4.0, 5.0]))
    assert a.dtype == np.float64 and a.flags.c_contiguous
    np.testing.assert_array_equal(a, [0.0, 2.0, 4.0, 6.0, 8.0])
    np.testing.assert_array_equal(b, [1.0, 2.0, 3.0, 4.0, 5.0])


@pytest.mark.parametrize('arrays, message', [
    (([1.0, 2.0], [1.0]), 'u, y and z must have equal length, got 2, 1 and 2'),
    (([1.0, np.nan], [1.0, 2.0]), 'u holds non-finite samples'),
    (([1.0, 2.0], [np.inf, 2.0]), 'y holds non-finite samples'),
    ((np.zeros((2, 2)), [1.0, 2.0]), r'u must be a non-empty 1-D array, got shape \(2, 2\)'),
    (([], []), 'u must be a non-empty 1-D array'),
])
def test_bad_records_are_named_with_the_callers_error(arrays, message):
    third = [0.0] * 2 if len(arrays[0]) != 1 else [0.0]
    with pytest.raises(IdentificationError, match=message):
        same_clock_records(('u', 'y', 'z'), arrays + (third,), IdentificationError)


def test_empty_records_only_when_allowed():
    a, b = same_clock_records(('a', 'b'), ([], []), allow_empty=True)
    assert a.size == 0 and b.size == 0
    with pytest.raises(ValueError, match='a must be a 1-D array'):
        same_clock_records(('a', 'b'), (np.zeros((1, 0)), []), allow_empty=True)
