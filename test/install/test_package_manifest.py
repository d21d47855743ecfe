"""
package.xml declares what the installed code imports (the stand-in for ``rosdep install``).

``rosdep install --from-paths src`` (docs/install.md, 3.) installs a package's ``package.xml``
dependencies; it needs a ROS distribution and its database, which are not here. This checks
the input it reads: every ROS package and library the installed modules and launch files
import is an
``exec_depend`` (Python libraries under their rosdep keys), except the libraries the install
page says to install with pip (``rosbags``, ``mcap``, ``threadpoolctl``) and the optional extra
``plot`` (``matplotlib``). numba is a requirement (issue 14): in ``install_requires`` and in
``package.xml`` under its rosdep key ``python3-numba``; the ``fast`` extra stays as an alias.
"""

import ast
from pathlib import Path
import sys
import xml.etree.ElementTree as ElementTree

REPO = Path(__file__).resolve().parents[2]
#: rosdep keys of the Python libraries.
ROSDEP_KEYS = {'numpy': 'python3-numpy', 'scipy': 'python3-scipy', 'yaml': 'python3-yaml',
               'numba': 'python3-numba'}
#: Not from rosdep: docs/install.md's `pip install rosbags mcap threadpoolctl`, and the optional
#: extras plot and daqmx (NI's nidaqmx client, its grpc, and the session_pb2 module its
#: gRPC stubs import).
PIP_ONLY = {'rosbags', 'mcap', 'threadpoolctl', 'matplotlib', 'nidaqmx', 'grpc', 'session_pb2'}


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
    # the installed modules and the launch files (they import launch and launch_ros)
    imported = imported_top_level(REPO / 'emfc_ros') | imported_top_level(REPO / 'launch')
    needed = {ROSDEP_KEYS.get(n, n) for n in imported} - PIP_ONLY
    assert needed - declared == set(), 'imported but not in package.xml'
    assert declared - needed == set(), 'in package.xml but never imported'
    assert manifest.find('export/build_type').text == 'ament_python'
    install = (REPO / 'docs' / 'install.md').read_text()
    assert 'pip install rosbags mcap threadpoolctl' in install
    setup_py = (REPO / 'setup.py').read_text()
    for extra, lib in (('fast', 'numba'), ('plot', 'matplotlib'), ('daqmx', 'nidaqmx')):
        assert f"'{extra}': ['{lib}" in setup_py
    assert "'.[daqmx]'" in install and "'.[daqmx]'" in (REPO / 'README.md').read_text()


def _install_requires() -> list:
    tree = ast.parse((REPO / 'setup.py').read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.keyword) and node.arg == 'install_requires':
            value = node.value
            if isinstance(value, ast.BinOp):        # [...] + ROS_FROM_PYPI
                value = value.left
            return [ast.literal_eval(e) for e in value.elts]
    raise AssertionError('setup.py has no install_requires')


def test_numba_is_a_requirement_and_an_exec_depend():
    # `pip install .` gets the compiled kernels (issue 14 item 3)
    requires = _install_requires()
    assert any(r.startswith('numba') for r in requires), requires
    manifest = ElementTree.parse(REPO / 'package.xml').getroot()
    assert 'python3-numba' in {e.text.strip() for e in manifest.iter('exec_depend')}
