"""
Public names of a package imported on first use (PEP 562), shared by the heavy packages.

``emfc_ros.core.ident`` and ``emfc_ros.core.report`` list each public name with the submodule
that holds it; the submodule (and scipy, matplotlib behind it) is imported only when the name
is first used, so that a light submodule (the run plan's check) stays light.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any, Callable, Dict, Mapping


def lazy_getattr(package: str, table: Mapping[str, str],
                 namespace: Dict[str, Any]) -> Callable[[str], Any]:
    """
    A module ``__getattr__`` that imports a public name from its submodule on first use.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    table : mapping of str to str
        Public name to the submodule (relative to the package) that holds it.
    namespace : dict
        The package's ``globals()``: the name is bound there once imported.

    Returns
    -------
    callable
        The ``__getattr__`` to bind in the package.
    """
    def __getattr__(name: str) -> Any:      # noqa: N807 - PEP 562 module hook
        module = table.get(name)
        if module is None:
            raise AttributeError(f'module {package!r} has no attribute {name!r}')
        value = getattr(import_module(f'{package}.{module}'), name)
        namespace[name] = value
        return value
    return __getattr__
