"""
The import structure tells the truth about the layers (read from the sources, not imported).

- no module of the package imports itself through others (no import circle);
- no circle between the packages of ``core`` but the one through ``core.ident`` (issue 26
  splits that package);
- ``core/device/backend.py`` (the interface) imports no back-end and not the registry, and no
  back-end imports the registry;
- the hardware path (the daq_bridge node, the node helpers, the device layer but the
  simulated device) imports no simulator or weighing module;
- nothing outside the registry branches on a back-end's name.
"""

import ast
import pathlib
from typing import Dict, List, Set

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from emfc_ros.core.device.registry import BACKENDS

ROOT = pathlib.Path(__file__).resolve().parents[2] / 'emfc_ros'
DEVICE = 'emfc_ros.core.device'
BACKEND_MODULES = {f'{DEVICE}.{name}_backend' for name in BACKENDS}
#: Modules on the way to the hardware: they must not lean on the simulator or weighing.
HARDWARE_PATH = ('emfc_ros.nodes.daq_bridge', 'emfc_ros.nodes.convert', 'emfc_ros.nodes.params',
                 'emfc_ros.nodes.spin', 'emfc_ros.nodes.flow_control')
#: The device modules that are the simulation (a back-end like any other, the emulator of a
#: UDP device built on it, and the simulated balance on the emulated NI-DAQmx device's
#: terminals).
SIMULATED_DEVICE = (f'{DEVICE}.sim_backend', f'{DEVICE}.emulator',
                    f'{DEVICE}.daqmx_emulator.plant')


def _modules() -> Dict[str, pathlib.Path]:
    mods = {}
    for path in ROOT.rglob('*.py'):
        parts = list(path.relative_to(ROOT.parent).with_suffix('').parts)
        if parts[-1] == '__init__':
            parts = parts[:-1]
        mods['.'.join(parts)] = path
    return mods


MODULES = _modules()


def _resolve(name: str) -> str:
    while name and name not in MODULES:
        name = name.rpartition('.')[0]
    return name


def _imports(path: pathlib.Path) -> Set[str]:
    """Every emfc_ros module a file imports, at any depth (lazy imports count)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out.update(_resolve(a.name) for a in node.names if a.name.startswith('emfc_ros'))
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module and \
                node.module.startswith('emfc_ros'):
            for alias in node.names:
                full = f'{node.module}.{alias.name}'
                out.add(full if full in MODULES else _resolve(node.module))
    return out


EDGES = {name: _imports(path) - {name} for name, path in MODULES.items()}


def _circles(edges: Dict[str, Set[str]]) -> List[List[str]]:
    """The strongly connected groups of more than one node."""
    nodes = sorted(set(edges) | {b for bs in edges.values() for b in bs})
    index = {n: i for i, n in enumerate(nodes)}
    rows = [index[a] for a, bs in edges.items() for _ in bs]
    cols = [index[b] for bs in edges.values() for b in bs]
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(nodes), len(nodes)))
    _, labels = connected_components(graph, directed=True, connection='strong')
    groups: Dict[int, List[str]] = {}
    for node, label in zip(nodes, labels):
        groups.setdefault(int(label), []).append(node)
    return [g for g in groups.values() if len(g) > 1]


def _package(module: str) -> str:
    parts = module.split('.')
    return '.'.join(parts[:3]) if parts[:2] == ['emfc_ros', 'core'] else '.'.join(parts[:2])


def test_the_graph_is_read_from_the_sources():
    assert len(MODULES) > 100 and f'{DEVICE}.registry' in MODULES
    assert f'{DEVICE}.backend' in EDGES[f'{DEVICE}.registry']
    assert _circles({'a': {'b'}, 'b': {'c'}, 'c': {'a'}, 'd': {'a'}}) == [['a', 'b', 'c']]


def test_no_module_imports_itself_through_others():
    assert _circles(EDGES) == []


def test_core_packages_form_no_circle_but_through_the_identification():
    packages: Dict[str, Set[str]] = {}
    for module, imported in EDGES.items():
        if module.startswith('emfc_ros.core'):
            packages.setdefault(_package(module), set()).update(
                _package(m) for m in imported if _package(m) != _package(module))
    circles = _circles(packages)
    assert all('emfc_ros.core.ident' in c for c in circles), circles


def test_the_device_interface_imports_no_backend_and_backends_not_the_registry():
    interface = EDGES[f'{DEVICE}.backend']
    assert not interface & (BACKEND_MODULES | {f'{DEVICE}.registry', DEVICE}), interface
    assert BACKEND_MODULES <= set(MODULES)
    for module in BACKEND_MODULES:
        assert f'{DEVICE}.registry' not in EDGES[module] and DEVICE not in EDGES[module], module


def test_the_hardware_path_imports_no_simulator_or_weighing_module():
    device = [m for m in MODULES if m.startswith(f'{DEVICE}.') and m not in SIMULATED_DEVICE]
    offenders = {m: sorted(i for i in EDGES[m] if i.startswith(('emfc_ros.core.sim',
                                                                'emfc_ros.core.weighing')))
                 for m in (*HARDWARE_PATH, *device)}
    assert {m: i for m, i in offenders.items() if i} == {}


def test_nothing_outside_the_registry_branches_on_a_backend_name():
    names = set(BACKENDS)
    found = []
    for module, path in MODULES.items():
        if not module.startswith(('emfc_ros.nodes', DEVICE)) or module == f'{DEVICE}.registry':
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Compare):
                consts = [c.value for c in (node.left, *node.comparators)
                          if isinstance(c, ast.Constant)]
                consts += [e.value for c in node.comparators if isinstance(c, (ast.Tuple,
                                                                               ast.List))
                           for e in c.elts if isinstance(e, ast.Constant)]
                if names & {c for c in consts if isinstance(c, str)}:
                    found.append(f'{module}:{node.lineno}')
    assert found == []
