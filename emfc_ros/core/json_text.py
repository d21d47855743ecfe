"""
JSON from other processes (stream descriptions, node status), parsed with bounds.

``json.loads`` of 100 000 nested ``[`` raises ``RecursionError``, not ``ValueError``; a
document nested a few hundred levels deep parses, but then breaks whoever walks it
recursively (``yaml.safe_dump`` into a bag's custom data, ``dataclasses.asdict``).
:func:`load_json_text` refuses both, and documents above :data:`MAX_JSON_BYTES`, with one
error class, :class:`JsonRefused` (a ``ValueError``), naming what was refused.
"""

from __future__ import annotations

import json
from typing import Any, Iterable, Union

from emfc_ros.core.errors import EmfcError

#: Largest document accepted [bytes].
MAX_JSON_BYTES = 4 * 2 ** 20
#: Deepest nesting of arrays and objects accepted.
MAX_JSON_DEPTH = 64


class JsonRefused(EmfcError, ValueError):
    """A JSON text is malformed, too large or nested too deep."""


def load_json_text(text: Union[str, bytes], what: str = 'JSON document',
                   max_depth: int = MAX_JSON_DEPTH, max_bytes: int = MAX_JSON_BYTES) -> Any:
    """
    Parse JSON text within bounds.

    Parameters
    ----------
    text : str or bytes
        The document (bytes must be UTF-8).
    what : str
        What it is, for the message (``'stream description'``).
    max_depth : int
        Deepest nesting of arrays and objects allowed.
    max_bytes : int
        Longest text allowed [bytes, or characters for str].

    Returns
    -------
    object
        The parsed value.

    Raises
    ------
    JsonRefused
        If the text is not a str or bytes, too long, not UTF-8, not JSON, or nested deeper
        than ``max_depth`` (including nesting deep enough to exhaust the parser's recursion).
    """
    if not isinstance(text, (str, bytes, bytearray)):
        raise JsonRefused(f'{what}: expected text, got {type(text).__name__}')
    if len(text) > max_bytes:
        raise JsonRefused(f'{what}: {len(text)} bytes, more than the {max_bytes} allowed')
    try:
        doc = json.loads(text)
    except RecursionError:
        raise JsonRefused(f'{what}: nested too deep to parse (more than {max_depth} levels '
                          'allowed)') from None
    except (ValueError, TypeError) as exc:      # JSONDecodeError, UnicodeDecodeError
        raise JsonRefused(f'{what}: not valid JSON: {exc}') from None
    depth = nesting_depth(doc, max_depth + 1)
    if depth > max_depth:
        raise JsonRefused(f'{what}: nested more than {max_depth} levels deep')
    return doc


def nesting_depth(doc: Any, stop: int) -> int:
    """
    Nesting depth of arrays and objects, counted without recursion.

    Parameters
    ----------
    doc : object
        A parsed JSON value.
    stop : int
        Stop counting once this depth is reached.

    Returns
    -------
    int
        0 for a scalar, 1 for a flat array or object, ...; at most ``stop``.
    """
    deepest = 0
    stack = [(doc, 1)]
    while stack:
        value, depth = stack.pop()
        children: Iterable[Any]
        if isinstance(value, dict):
            children = value.values()
        elif isinstance(value, list):
            children = value
        else:
            continue
        deepest = max(deepest, depth)
        if deepest >= stop:
            return deepest
        stack.extend((child, depth + 1) for child in children)
    return deepest
