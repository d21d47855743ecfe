"""
Every node executable resolves as `ros2 run emfc_ros <name>` resolves it, and starts.

Checked for a pip install into a prefix, for `colcon build` and for
`colcon build --symlink-install`: the ament index marker is found in a prefix of
AMENT_PREFIX_PATH, `<prefix>/lib/emfc_ros/<name>` is an executable file, and running it
brings up the node over real DDS.
"""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import ros_harness
from ros_harness import scaled

REPO = Path(__file__).resolve().parents[2]
#: A fresh install has no numba cache: the plant simulator compiles its kernel (12-17 s
#: measured here) before its node appears.
FIRST_START_TIMEOUT_S = scaled(180.0)
NODES = ['signal_generator', 'plant_simulator', 'recorder', 'identifier', 'daq_bridge']
IGNORE = shutil.ignore_patterns('.venv', 'build', 'install', 'log', '.git', '__pycache__',
                                '*.egg-info', 'out', '.pytest_cache', '.hypothesis', 'bench')


def _copy_source(dest: Path) -> Path:
    shutil.copytree(REPO, dest, ignore=IGNORE)
    return dest


def _node_names(executor, node):
    executor.spin_once(timeout_sec=0.05)
    return [name for name, _ns in node.get_node_names_and_namespaces()]


def _start_and_see_node(processes, executor, ros_context, exe: Path, env: dict, cwd: Path,
                        node_name: str):
    import rclpy

    probe = rclpy.create_node('install_probe', context=ros_context)
    executor.add_node(probe)
    proc = processes.start([str(exe), '--ros-args', '-r', f'__node:={node_name}',
                            '-p', 'autostart:=false'], env=env, cwd=cwd)
    seen = ros_harness.wait_until(lambda: node_name in _node_names(executor, probe),
                                  FIRST_START_TIMEOUT_S)
    assert seen, f'{node_name} not discovered; output:\n{proc.output()}'
    assert proc.stop() == 0, proc.output()


def _assert_resolves(prefix: Path, name: str) -> Path:
    marker = prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' / 'emfc_ros'
    assert marker.is_file()
    exe = ros_harness.resolve_ros2run('emfc_ros', name, str(prefix))
    assert exe == prefix / 'lib' / 'emfc_ros' / name
    assert os.access(exe, os.X_OK)
    return exe


def test_resolver_refuses_missing_package_and_non_executable(tmp_path):
    with pytest.raises(LookupError, match='not found'):
        ros_harness.resolve_ros2run('emfc_ros', 'signal_generator', str(tmp_path))
    marker = tmp_path / 'share' / 'ament_index' / 'resource_index' / 'packages'
    marker.mkdir(parents=True)
    (marker / 'emfc_ros').touch()
    (tmp_path / 'lib' / 'emfc_ros').mkdir(parents=True)
    (tmp_path / 'lib' / 'emfc_ros' / 'signal_generator').write_text('#!/bin/sh\n')
    with pytest.raises(LookupError, match='not an executable'):
        ros_harness.resolve_ros2run('emfc_ros', 'signal_generator', str(tmp_path))


@pytest.mark.slow
def test_pip_install_into_a_prefix(tmp_path, processes, executor, ros_context):
    src = _copy_source(tmp_path / 'src')
    prefix = tmp_path / 'prefix'
    # --ignore-installed: otherwise pip uninstalls the copy in the running environment.
    subprocess.run([sys.executable, '-m', 'pip', 'install', '-q', '--no-deps', '--ignore-installed',
                    '--no-build-isolation', '--prefix', str(prefix), str(src)],
                   check=True, timeout=scaled(300), cwd=tmp_path)
    site = prefix / 'lib' / f'python{sys.version_info[0]}.{sys.version_info[1]}' / \
        'site-packages'
    env = {'AMENT_PREFIX_PATH': str(prefix), 'PYTHONPATH': str(site)}
    where = subprocess.run([sys.executable, '-c', 'import emfc_ros; print(emfc_ros.__file__)'],
                           env=ros_harness.child_environment(env), cwd=tmp_path,
                           capture_output=True, text=True, check=True, timeout=scaled(60)).stdout
    assert where.startswith(str(site)), where
    for name in NODES:
        exe = _assert_resolves(prefix, name)
        _start_and_see_node(processes, executor, ros_context, exe, env, tmp_path,
                            f'pip_{name}')


def _colcon_env(install: Path) -> dict:
    script = f'. "{install}/local_setup.sh" && env -0'
    out = subprocess.run(['sh', '-c', script], capture_output=True, check=True,
                         timeout=scaled(60), env=ros_harness.child_environment(),
                         cwd=install.parent).stdout
    env = dict(item.split('=', 1) for item in out.decode().split('\0') if '=' in item)
    return {k: env[k] for k in ('AMENT_PREFIX_PATH', 'PYTHONPATH', 'PATH') if k in env}


@pytest.mark.slow
@pytest.mark.parametrize('symlink', [False, True], ids=['copy', 'symlink'])
def test_colcon_build(tmp_path, processes, executor, ros_context, symlink):
    colcon = shutil.which('colcon') or str(Path(sys.executable).parent / 'colcon')
    assert Path(colcon).exists(), 'colcon is installed by tools/setup_env.sh'
    ws = tmp_path / 'ws'
    _copy_source(ws / 'src' / 'emfc_ros')
    cmd = [colcon, '--log-base', str(ws / 'log'), 'build', '--base-paths', str(ws / 'src'),
           '--build-base', str(ws / 'build'), '--install-base', str(ws / 'install')]
    if symlink:
        cmd.append('--symlink-install')
    result = subprocess.run(cmd, cwd=ws, capture_output=True, text=True, timeout=scaled(600),
                            env=ros_harness.child_environment())
    assert result.returncode == 0, result.stdout + result.stderr
    prefix = ws / 'install' / 'emfc_ros'
    env = _colcon_env(ws / 'install')
    assert str(prefix) in env['AMENT_PREFIX_PATH'].split(os.pathsep)
    for name in NODES:
        exe = _assert_resolves(prefix, name)
        if symlink:
            assert exe.is_symlink() or exe.resolve() != exe
        _start_and_see_node(processes, executor, ros_context, exe, env, ws,
                            f'colcon_{name}')
