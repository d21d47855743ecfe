"""Code style: ament_flake8's rules as configured in setup.cfg, on the whole package."""

from pathlib import Path
import subprocess
import sys

from ros_harness import scaled

REPO = Path(__file__).resolve().parents[1]


def test_flake8_is_clean():
    targets = [p for p in ('emfc_ros', 'test', 'bench', 'launch', 'setup.py')
               if (REPO / p).exists()]
    result = subprocess.run([sys.executable, '-m', 'flake8', *targets], cwd=REPO,
                            capture_output=True, text=True, timeout=scaled(300))
    assert result.returncode == 0, result.stdout + result.stderr
