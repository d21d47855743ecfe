"""The numerical core must not import rclpy or any ROS message package."""

import ast
from pathlib import Path
import pkgutil
import subprocess
import sys

import emfc_ros.core
from ros_harness import scaled

CORE_DIR = Path(emfc_ros.core.__file__).parent
FORBIDDEN_ROOTS = ('rclpy', 'rosidl', 'rcl_interfaces', 'builtin_interfaces')


def _forbidden(module: str) -> bool:
    root = module.split('.')[0]
    return root in FORBIDDEN_ROOTS or root.endswith('_msgs') or root.endswith('_srvs')


def test_no_ros_import_statement_in_core_sources():
    offenders = []
    files = sorted(CORE_DIR.rglob('*.py'))
    assert len(files) >= 5, 'the core package should hold its modules'
    for path in files:
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module]
            offenders += [f'{path}:{node.lineno}: {n}' for n in names if _forbidden(n)]
    assert offenders == []


def test_importing_every_core_module_loads_no_ros_module():
    modules = [m.name for m in pkgutil.walk_packages(emfc_ros.core.__path__, 'emfc_ros.core.')]
    assert 'emfc_ros.core.blocks' in modules
    code = (
        'import importlib, sys\n'
        f'for name in {modules!r}:\n'
        '    importlib.import_module(name)\n'
        'print("\\n".join(sorted(sys.modules)))\n')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=scaled(120), check=True).stdout.split()
    loaded = [m for m in out if _forbidden(m)]
    assert loaded == []


def test_the_check_itself_detects_a_ros_import():
    assert _forbidden('rclpy.node')
    assert _forbidden('std_msgs.msg')
    assert _forbidden('std_srvs.srv')
    assert not _forbidden('numpy')
