"""
Validated access to nested configuration mappings (parsed YAML or ROS parameters).

Every getter takes the mapping, the key and the dotted path of the mapping, and raises
:class:`~emfc_ros.core.errors.ConfigError` naming the full key and the allowed range.
"""

from __future__ import annotations

import math
from typing import Any, Iterable, Mapping, Optional, Sequence

from emfc_ros.core.errors import ConfigError

_MISSING = object()


def join(path: str, key: str) -> str:
    """
    Join a dotted path and a key.

    Parameters
    ----------
    path : str
        Dotted path of the enclosing mapping ('' at the top).
    key : str
        Key inside that mapping.

    Returns
    -------
    str
        ``path.key`` or ``key`` at the top level.
    """
    return f'{path}.{key}' if path else key


def get_float(cfg: Mapping[str, Any], key: str, path: str = '', *,
              default: Any = _MISSING, minimum: Optional[float] = None,
              maximum: Optional[float] = None, min_exclusive: bool = False) -> float:
    """
    Read a finite float, accepting ints, with optional bounds.

    Parameters
    ----------
    cfg : Mapping
        The mapping to read from.
    key : str
        The key.
    path : str
        Dotted path of ``cfg`` for error messages.
    default : float, optional
        Value when the key is absent; without it the key is required.
    minimum, maximum : float, optional
        Inclusive bounds (``minimum`` exclusive when ``min_exclusive``).
    min_exclusive : bool
        Treat ``minimum`` as exclusive.

    Returns
    -------
    float
        The validated value.

    Raises
    ------
    ConfigError
        If the key is missing, not a number, not finite or out of range.
    """
    name = join(path, key)
    value = cfg.get(key, _MISSING) if isinstance(cfg, Mapping) else _MISSING
    if value is _MISSING:
        if default is _MISSING:
            raise ConfigError(name, 'required key is missing')
        return float(default)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(name, f'expected a number, got {value!r}')
    value = float(value)
    if not math.isfinite(value):
        raise ConfigError(name, f'expected a finite number, got {value!r}')
    _check_range(name, value, minimum, maximum, min_exclusive)
    return value


def get_int(cfg: Mapping[str, Any], key: str, path: str = '', *,
            default: Any = _MISSING, minimum: Optional[int] = None,
            maximum: Optional[int] = None) -> int:
    """
    Read an integer (a float with an integral value is accepted) with optional bounds.

    Parameters
    ----------
    cfg : Mapping
        The mapping to read from.
    key : str
        The key.
    path : str
        Dotted path of ``cfg`` for error messages.
    default : int, optional
        Value when the key is absent; without it the key is required.
    minimum, maximum : int, optional
        Inclusive bounds.

    Returns
    -------
    int
        The validated value.

    Raises
    ------
    ConfigError
        If the key is missing, not an integer or out of range.
    """
    name = join(path, key)
    value = cfg.get(key, _MISSING) if isinstance(cfg, Mapping) else _MISSING
    if value is _MISSING:
        if default is _MISSING:
            raise ConfigError(name, 'required key is missing')
        return int(default)
    if isinstance(value, bool):
        raise ConfigError(name, f'expected an integer, got {value!r}')
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if not isinstance(value, int):
        raise ConfigError(name, f'expected an integer, got {value!r}')
    _check_range(name, value, minimum, maximum, False)
    return value


def get_bool(cfg: Mapping[str, Any], key: str, path: str = '', *,
             default: Any = _MISSING) -> bool:
    """
    Read a boolean.

    Parameters
    ----------
    cfg : Mapping
        The mapping to read from.
    key : str
        The key.
    path : str
        Dotted path of ``cfg`` for error messages.
    default : bool, optional
        Value when the key is absent; without it the key is required.

    Returns
    -------
    bool
        The value.

    Raises
    ------
    ConfigError
        If the key is missing or not a boolean.
    """
    name = join(path, key)
    value = cfg.get(key, _MISSING) if isinstance(cfg, Mapping) else _MISSING
    if value is _MISSING:
        if default is _MISSING:
            raise ConfigError(name, 'required key is missing')
        return bool(default)
    if not isinstance(value, bool):
        raise ConfigError(name, f'expected true or false, got {value!r}')
    return value


def get_str(cfg: Mapping[str, Any], key: str, path: str = '', *,
            default: Any = _MISSING, choices: Optional[Iterable[str]] = None) -> str:
    """
    Read a string, optionally one of fixed choices.

    Parameters
    ----------
    cfg : Mapping
        The mapping to read from.
    key : str
        The key.
    path : str
        Dotted path of ``cfg`` for error messages.
    default : str, optional
        Value when the key is absent; without it the key is required.
    choices : iterable of str, optional
        The allowed values.

    Returns
    -------
    str
        The value.

    Raises
    ------
    ConfigError
        If the key is missing, not a string or not one of ``choices``.
    """
    name = join(path, key)
    value = cfg.get(key, _MISSING) if isinstance(cfg, Mapping) else _MISSING
    if value is _MISSING:
        if default is _MISSING:
            raise ConfigError(name, 'required key is missing')
        value = default
    if not isinstance(value, str):
        raise ConfigError(name, f'expected a string, got {value!r}')
    if choices is not None:
        allowed = list(choices)
        if value not in allowed:
            raise ConfigError(name, f'{value!r} is not one of {allowed}')
    return value


def get_float_list(cfg: Mapping[str, Any], key: str, path: str = '', *,
                   default: Any = _MISSING, min_length: int = 0,
                   minimum: Optional[float] = None,
                   maximum: Optional[float] = None) -> list:
    """
    Read a list of finite floats with optional element bounds.

    Parameters
    ----------
    cfg : Mapping
        The mapping to read from.
    key : str
        The key.
    path : str
        Dotted path of ``cfg`` for error messages.
    default : list of float, optional
        Value when the key is absent; without it the key is required.
    min_length : int
        Minimum number of elements.
    minimum, maximum : float, optional
        Inclusive bounds for every element.

    Returns
    -------
    list of float
        The validated values.

    Raises
    ------
    ConfigError
        If the key is missing, not a list of numbers, too short or out of range.
    """
    name = join(path, key)
    value = cfg.get(key, _MISSING) if isinstance(cfg, Mapping) else _MISSING
    if value is _MISSING:
        if default is _MISSING:
            raise ConfigError(name, 'required key is missing')
        value = default
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
        raise ConfigError(name, f'expected a list of numbers, got {value!r}')
    out = []
    for i, item in enumerate(value):
        if isinstance(item, bool) or not isinstance(item, (int, float)):
            raise ConfigError(f'{name}[{i}]', f'expected a number, got {item!r}')
        item = float(item)
        if not math.isfinite(item):
            raise ConfigError(f'{name}[{i}]', f'expected a finite number, got {item!r}')
        _check_range(f'{name}[{i}]', item, minimum, maximum, False)
        out.append(item)
    if len(out) < min_length:
        raise ConfigError(name, f'expected at least {min_length} values, got {len(out)}')
    return out


def get_str_list(cfg: Mapping[str, Any], key: str, path: str = '', *,
                 default: Any = _MISSING, min_length: int = 0) -> list:
    """
    Read a list of strings.

    Parameters
    ----------
    cfg : Mapping
        The mapping to read from.
    key : str
        The key.
    path : str
        Dotted path of ``cfg`` for error messages.
    default : list of str, optional
        Value when the key is absent; without it the key is required.
    min_length : int
        Minimum number of elements.

    Returns
    -------
    list of str
        The values.

    Raises
    ------
    ConfigError
        If the key is missing, not a list of strings or too short.
    """
    name = join(path, key)
    value = cfg.get(key, _MISSING) if isinstance(cfg, Mapping) else _MISSING
    if value is _MISSING:
        if default is _MISSING:
            raise ConfigError(name, 'required key is missing')
        value = default
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence) or not all(
            isinstance(v, str) for v in value):
        raise ConfigError(name, f'expected a list of strings, got {value!r}')
    if len(value) < min_length:
        raise ConfigError(name, f'expected at least {min_length} entries, got {len(value)}')
    return list(value)


def get_mapping(cfg: Mapping[str, Any], key: str, path: str = '', *,
                default: Any = _MISSING) -> Mapping[str, Any]:
    """
    Read a nested mapping.

    Parameters
    ----------
    cfg : Mapping
        The mapping to read from.
    key : str
        The key.
    path : str
        Dotted path of ``cfg`` for error messages.
    default : Mapping, optional
        Value when the key is absent; without it the key is required.

    Returns
    -------
    Mapping
        The nested mapping.

    Raises
    ------
    ConfigError
        If the key is missing or not a mapping.
    """
    name = join(path, key)
    value = cfg.get(key, _MISSING) if isinstance(cfg, Mapping) else _MISSING
    if value is _MISSING:
        if default is _MISSING:
            raise ConfigError(name, 'required key is missing')
        return default
    if not isinstance(value, Mapping):
        raise ConfigError(name, f'expected a mapping, got {value!r}')
    return value


def reject_unknown(cfg: Mapping[str, Any], allowed: Iterable[str], path: str = '') -> None:
    """
    Refuse keys that are not recognised (catches typos such as ``amplitde_V``).

    Parameters
    ----------
    cfg : Mapping
        The mapping to check.
    allowed : iterable of str
        The recognised keys.
    path : str
        Dotted path of ``cfg`` for error messages.

    Raises
    ------
    ConfigError
        Naming the first unknown key and listing the recognised ones.
    """
    known = set(allowed)
    for key in cfg:
        if key not in known:
            raise ConfigError(join(path, str(key)),
                              f'unknown key; recognised keys are {sorted(known)}')


def unflatten(flat: Mapping[str, Any], sep: str = '.') -> dict:
    """
    Turn dotted keys (as ROS parameters are named) into nested dictionaries.

    Parameters
    ----------
    flat : Mapping
        Keys such as ``'section.coil_chirp.duration_s'``.
    sep : str
        The separator.

    Returns
    -------
    dict
        The nested dictionaries.

    Raises
    ------
    ConfigError
        If a key is used both as a value and as a mapping.
    """
    out: dict = {}
    for key in sorted(flat):
        parts = key.split(sep)
        node = out
        for i, part in enumerate(parts[:-1]):
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                raise ConfigError(sep.join(parts[:i + 1]), 'is both a value and a mapping')
            node = child
        if isinstance(node.get(parts[-1]), dict):
            raise ConfigError(key, 'is both a value and a mapping')
        node[parts[-1]] = flat[key]
    return out


def flatten(nested: Mapping[str, Any], sep: str = '.', prefix: str = '') -> dict:
    """
    Turn nested dictionaries into dotted keys (the inverse of :func:`unflatten`).

    Parameters
    ----------
    nested : Mapping
        Nested mappings; lists and scalars are leaves.
    sep : str
        The separator.
    prefix : str
        Prepended to every key (with the separator).

    Returns
    -------
    dict
        ``{'section.coil_chirp.duration_s': 10.0, ...}``.
    """
    out: dict = {}
    for key, value in nested.items():
        name = f'{prefix}{sep}{key}' if prefix else str(key)
        if isinstance(value, Mapping) and value:
            out.update(flatten(value, sep, name))
        else:
            out[name] = value
    return out


def _check_range(name: str, value: float, minimum: Optional[float],
                 maximum: Optional[float], min_exclusive: bool) -> None:
    if minimum is not None:
        if min_exclusive and not value > minimum:
            raise ConfigError(name, f'{value!r} must be greater than {minimum!r}')
        if not min_exclusive and value < minimum:
            raise ConfigError(name, f'{value!r} must be at least {minimum!r}')
    if maximum is not None and value > maximum:
        raise ConfigError(name, f'{value!r} must be at most {maximum!r}')
