"""Stand-in for ``launch_ros`` (see the docstring of the stand-in ``launch`` package)."""

import importlib
from typing import Any

from launch import refuse_missing


def __getattr__(name: str) -> Any:
    if name.startswith('__'):
        raise AttributeError(name)
    if name in ('actions', 'parameter_descriptions', 'substitutions'):
        return importlib.import_module(f'launch_ros.{name}')
    raise refuse_missing('launch_ros', name)
