"""
Launch files are valid Python and reference only executables and parameters that exist.

`launch` and `launch_ros` are not installable here, so the files are checked statically:
parsed, every ``Node(...)`` call's ``executable`` is one of the installed node wrappers and
every literal parameter name is one the node declares.
"""

import ast
from pathlib import Path

import pytest

from emfc_ros.nodes import daq_bridge, plant_simulator, signal_generator

REPO = Path(__file__).resolve().parents[2]
LAUNCH_FILES = sorted((REPO / 'launch').glob('*.launch.py'))
WRAPPERS = {p.name for p in (REPO / 'lib_wrappers').iterdir()}
# Parameters every rclpy node has, plus each node's own.
COMMON = {'use_sim_time'}
NODE_PARAMETERS = {'signal_generator': set(signal_generator.PARAMETERS) | COMMON,
                   'plant_simulator': set(plant_simulator.PARAMETERS) | COMMON,
                   'daq_bridge': set(daq_bridge.PARAMETERS) | COMMON}


def _node_calls(tree):
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, 'id', None) == 'Node':
            yield {kw.arg: kw.value for kw in node.keywords}


def test_there_are_launch_files():
    assert LAUNCH_FILES


@pytest.mark.parametrize('path', LAUNCH_FILES, ids=lambda p: p.name)
def test_launch_file_references_existing_executables_and_parameters(path):
    tree = ast.parse(path.read_text(), filename=str(path))
    compile(tree, str(path), 'exec')
    assert any(isinstance(n, ast.FunctionDef) and n.name == 'generate_launch_description'
               for n in tree.body)
    calls = list(_node_calls(tree))
    assert calls, 'a launch file should start at least one node'
    for kwargs in calls:
        assert ast.literal_eval(kwargs['package']) == 'emfc_ros'
        executable = ast.literal_eval(kwargs['executable'])
        assert executable in WRAPPERS, executable
        for params in getattr(kwargs.get('parameters'), 'elts', []):
            if isinstance(params, ast.Dict):
                for key in params.keys:
                    name = ast.literal_eval(key)
                    assert name in NODE_PARAMETERS[executable] or name.startswith(
                        ('experiment.', 'balance.')), \
                        f'{path.name}: {executable} has no parameter {name}'
