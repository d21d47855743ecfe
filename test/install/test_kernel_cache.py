"""
numba's kernels compiled ahead into the installed package's cache, and reused (issue 14).

Runs the README's ``emfc-compile-kernels`` as typed in the test's virtual environment (a
non-editable ``pip install .``, as ``tools/setup_env.sh`` makes it): every kernel is compiled
or loaded, its cache lives in that environment's ``site-packages`` (next to the installed
module, not in the checkout), a second run loads every kernel from it, and a program's own
code path (a simulator built in a fresh process) finds the compiled chain there and compiles
nothing.
"""

from pathlib import Path
import re
import subprocess
import sys
import sysconfig

import pytest

import readme_lines
import ros_harness
from ros_harness import scaled

LINE = re.compile(r'^(?P<name>[^:]+): (?P<how>compiled|loaded) (?P<n>\d+) signature\(s\)'
                  r'.* in (?P<s>[\d.]+) s \((?P<path>.+)\)$')


def _prepare() -> dict:
    argv = readme_lines.readme_argv('emfc-compile-kernels')
    result = subprocess.run(argv, capture_output=True, text=True, timeout=scaled(900),
                            env=ros_harness.child_environment())
    assert result.returncode == 0, result.stdout + result.stderr
    kernels = {}
    for line in result.stdout.splitlines():
        match = LINE.match(line)
        assert match, f'unexpected line {line!r}'
        kernels[match['name']] = match.groupdict()
    return kernels


@pytest.mark.slow
def test_the_kernels_compile_into_site_packages_and_are_reused():
    from emfc_ros.core.kernels import KERNELS

    site = Path(sysconfig.get_paths()['purelib']).resolve()
    import emfc_ros
    installed = Path(emfc_ros.__file__).resolve().parent
    assert site in installed.parents, f'the tests must run against an install: {installed}'
    first = _prepare()
    assert set(first) == set(KERNELS)
    for name, row in first.items():
        cache = Path(row['path']).resolve()
        assert installed in cache.parents and cache.name == '__pycache__', (name, cache)
        assert any(cache.glob('*.nbi')) and any(cache.glob('*.nbc')), (name, cache)
    second = _prepare()
    assert {name: row['how'] for name, row in second.items()} == {
        name: 'loaded' for name in KERNELS}, second
    # the simulator as any program builds it, in a process of its own
    probe = ('from emfc_ros.core.model.parameters import BalanceParameters\n'
             'from emfc_ros.core.sim.simulator import Simulator, _jitted\n'
             'Simulator(BalanceParameters(), 10000.0)\n'
             'stats = _jitted().stats\n'
             'print(stats.cache_hits.total(), stats.cache_misses.total(), stats.cache_path)\n')
    result = subprocess.run([sys.executable, '-c', probe], capture_output=True, text=True,
                            timeout=scaled(300), env=ros_harness.child_environment(), cwd='/')
    assert result.returncode == 0, result.stderr
    hits, misses, path = result.stdout.split(maxsplit=2)
    assert (int(hits), int(misses)) == (1, 0), result.stdout
    assert Path(path.strip()).resolve().parent.parent == installed / 'core', path
