"""
Skip scipy's import-time docstring rewriting in the experiment runner's processes.

scipy (1.15 and later) decorates its public functions with ``xp_capabilities``, which at
import time parses each docstring with a numpydoc parser and appends a table of the array
backends the function supports. For ``scipy.signal`` and ``scipy.stats`` that is about 800
docstrings: 1.1-1.5 s of CPU for the two imports on this machine against 0.6-0.7 s without
it (``docs/benchmarks.md``, main job), paid in every process that imports them. The
experiment runner and its plot workers never show scipy's docstrings, so they skip it
(:func:`skip_docstring_notes`, called before scipy is imported): the decorator still records
each function's capabilities, and the docstring stays scipy's own text, without the appended
table. Nothing numerical changes. A library user who imports emfc_ros is not affected: only
the runner's entry point and its plot workers call it. On a scipy without that internal
layout it changes nothing.
"""

from __future__ import annotations

from typing import Any, Dict, List


class _PlainDoc:
    """Stands in for scipy's ``FunctionDoc`` in ``xp_capabilities``: the docstring as it is."""

    def __init__(self, func: Any, *args: Any, **kwargs: Any) -> None:
        self._doc = getattr(func, '__doc__', None) or ''
        self._sections: Dict[str, List[str]] = {}

    def __getitem__(self, key: str) -> List[str]:
        return self._sections.setdefault(key, [])

    def __str__(self) -> str:
        # the decorator drops the first line (numpydoc's signature line) and strips the rest
        return 'signature\n' + self._doc


def skip_docstring_notes() -> bool:
    """
    Make scipy's ``xp_capabilities`` leave docstrings as they are (this process only).

    Returns
    -------
    bool
        True when applied; False when this scipy has no such decorator (nothing changed) or
        scipy is not installed.
    """
    try:
        from scipy._lib import _array_api
    except ImportError:
        return False
    if not callable(getattr(_array_api, 'xp_capabilities', None)) or \
            getattr(_array_api, 'FunctionDoc', None) is None:
        return False
    _array_api.FunctionDoc = _PlainDoc
    return True
