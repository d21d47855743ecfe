"""The runner's skipping of scipy's import-time docstring rewriting changes no number."""

import json
import subprocess
import sys

CODE = r"""
import json, sys
import numpy as np
if sys.argv[1] == 'skip':
    from emfc_ros.core.scipy_docs import skip_docstring_notes
    applied = skip_docstring_notes()
else:
    applied = None
import scipy.signal, scipy.stats
from scipy._lib._array_api import xp_capabilities_table
rng = np.random.default_rng(7)
x = rng.standard_normal(4096)
f, p = scipy.signal.welch(x, fs=100.0, nperseg=256)
print(json.dumps({'applied': applied, 'psd': p.tolist(), 'f': f.tolist(),
                  'norm': float(scipy.stats.norm.ppf(0.975)),
                  'doc': scipy.signal.welch.__doc__,
                  'registered': scipy.signal.welch in xp_capabilities_table}))
"""


def _run(mode: str) -> dict:
    done = subprocess.run([sys.executable, '-c', CODE, mode], capture_output=True, text=True,
                          timeout=120, check=True)
    return json.loads(done.stdout)


def test_same_numbers_plain_docstrings_capabilities_kept():
    """Same welch PSD and norm quantile; the docstring is scipy's own text without the note."""
    plain, skipped = _run('plain'), _run('skip')
    assert skipped['applied'] is True
    assert skipped['psd'] == plain['psd'] and skipped['f'] == plain['f']
    assert skipped['norm'] == plain['norm']
    assert skipped['registered'] and plain['registered']
    # scipy's own text is kept; only the appended backend table is missing
    assert 'Estimate power spectral density' in skipped['doc']
    assert 'Array API Standard Support' in plain['doc']
    assert 'Array API Standard Support' not in skipped['doc']
