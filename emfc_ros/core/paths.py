"""
Where the package's shared files (``config/``, ``launch/``) are installed.

Looks in the ament prefixes (``AMENT_PREFIX_PATH``), the running interpreter's prefix (a
``pip install .`` puts them in ``<venv>/share/emfc_ros``) and, for a source checkout, the
repository itself.
"""

from __future__ import annotations

import os
from pathlib import Path
import sys
from typing import List

PACKAGE = 'emfc_ros'


def share_directories() -> List[Path]:
    """
    Candidate ``share/emfc_ros`` folders, most specific first.

    Returns
    -------
    list of pathlib.Path
        Existing folders only.
    """
    candidates = []
    for prefix in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep):
        if prefix:
            candidates.append(Path(prefix) / 'share' / PACKAGE)
    candidates.append(Path(sys.prefix) / 'share' / PACKAGE)
    candidates.append(Path(__file__).resolve().parents[2])
    seen = []
    for path in candidates:
        if path.is_dir() and (path / 'config').is_dir() and path not in seen:
            seen.append(path)
    return seen


def config_file(name: str) -> Path:
    """
    Path of a shipped configuration file.

    Parameters
    ----------
    name : str
        File name inside ``config/``, for example ``'identification_trajectory.yaml'``.

    Returns
    -------
    pathlib.Path
        The first existing match.

    Raises
    ------
    FileNotFoundError
        If no share directory holds it.
    """
    for share in share_directories():
        path = share / 'config' / name
        if path.is_file():
            return path
    raise FileNotFoundError(f'config/{name} not found in any emfc_ros share directory '
                            f'(set AMENT_PREFIX_PATH to the install prefix)')
