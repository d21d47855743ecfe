"""
package.xml declares what the installed code imports (the stand-in for ``rosdep install``).

``rosdep install --from-paths src`` (README, install 3.) installs a package's ``package.xml``
dependencies; it needs a ROS distribution and its database, which are not here. This checks
the input it reads: every ROS package and library the installed modules import is an
``exec_depend`` (Python libraries under their rosdep keys), except the libraries the README
says to install with pip (``rosbags``, ``mcap``, ``threadpoolctl``) and the optional extras (``numba``: ``fast``,
``matplotlib``: ``plot``).
"""

import ast
from pathlib import Path
import sys
import xml.etree.ElementTree as ElementTree

REPO = Path(__file__).resolve().parents[2]
#: rosdep keys of the Python libraries.
ROSDEP_KEYS = {'numpy': 'python3-numpy', 'scipy': 'python3-scipy', 'yaml': 'python3-yaml'}
#: Not from rosdep: the README's `pip install rosbags mcap threadpoolctl`, and the optional
#: extras.
PIP_ONLY = {'rosbags', 'mcap', 'threadpoolctl', 'numba', 'matplotlib'}


def imported_top_level(root: Path) -> set:
    names = set()
    for path in root.rglob('*.py'):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names.update(a.name.split('.')[0] for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module.split('.')[0])
    return {n for n in names if n not in sys.stdlib_module_names and n != 'emfc_ros'}


def test_every_import_is_an_exec_depend_or_a_documented_pip_install():
    manifest = ElementTree.parse(REPO / 'package.xml').getroot()
    declared = {e.text.strip() for e in manifest.iter('exec_depend')}
    needed = {ROSDEP_KEYS.get(n, n) for n in imported_top_level(REPO / 'emfc_ros')} - PIP_ONLY
    assert needed - declared == set(), 'imported but not in package.xml'
    assert declared - needed == set(), 'in package.xml but never imported'
    assert manifest.find('export/build_type').text == 'ament_python'
    readme = (REPO / 'README.md').read_text()
    assert 'pip install rosbags mcap threadpoolctl' in readme
    for extra, lib in (('fast', 'numba'), ('plot', 'matplotlib')):
        assert f"'{extra}': ['{lib}" in (REPO / 'setup.py').read_text()
