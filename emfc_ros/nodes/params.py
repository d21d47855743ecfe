"""
Parameter declaration shared by every node: descriptors with limits, and ``--help`` text.

Each node keeps its table ``PARAMETERS`` (name: ``(default, description)``, the weighing
node ``(default, description, read_only)``), plus optionally ``LIMITS`` (name: ``(min,
max)``, inclusive, in the parameter's unit) and ``READ_ONLY`` (names fixed at start-up).
:func:`declare_table` turns them into parameter descriptors with a ``FloatingPointRange``
or ``IntegerRange`` and ``read_only``, so that ``ros2 param describe`` shows the limits and
``ros2 param set`` is refused at once outside them. A node module may also keep
``PARAMETER_GROUPS`` (parameters declared once per item of another parameter: title to
``(text, table, limits)``, the names with a placeholder) and ``HELP_EXTRA`` (free text on
further parameters); :func:`node_table` gathers them all, for ``--help`` (:func:`help_text`)
and the parameter reference (:mod:`emfc_ros.nodes.param_reference`, ``docs/parameters.md``).

A start-up value (``-p name:=value``, a params file) outside the limits or of the wrong type
does not end the node: the parameter keeps its default, the problem is logged as an error
naming the parameter and returned, and the node reports it (state ``error`` and
``/diagnostics``) instead of running with a value nobody asked for.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Iterable, List, Mapping, Optional, Sequence, Tuple

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter

#: Inclusive ``(min, max)`` of a numeric parameter, in its unit.
Limits = Tuple[float, float]

#: Node attribute holding the names of the float parameters (integers are taken as floats).
FLOATS_ATTRIBUTE = '_emfc_float_parameters'
#: Node attribute holding the refused start-up values not yet replaced (name: message).
REFUSED_ATTRIBUTE = '_emfc_refused_start_up_values'
_TYPE_NAMES = {bool: 'bool', int: 'integer', float: 'double', str: 'string'}


def descriptor(default: Any, text: str, limits: Optional[Limits] = None,
               read_only: bool = False) -> ParameterDescriptor:
    """
    Build the descriptor of one table entry.

    Parameters
    ----------
    default : object
        The default value (its type selects the kind of range).
    text : str
        Description with the unit.
    limits : tuple of float, optional
        Inclusive ``(min, max)``; integers for integer parameters.
    read_only : bool, optional
        Fixed at start-up (``ros2 param set`` is refused).

    Returns
    -------
    rcl_interfaces.msg.ParameterDescriptor
        Name and type are filled in by ``declare_parameter``.

    Raises
    ------
    ValueError
        For limits on a parameter that is not an integer or a float, or min > max.
    """
    d = ParameterDescriptor(description=text, read_only=bool(read_only))
    if limits is None:
        return d
    low, high = limits
    if not low <= high:
        raise ValueError(f'limits ({low}, {high}): min must not exceed max')
    if isinstance(default, bool) or not isinstance(default, (int, float)):
        raise ValueError(f'limits on a non-numeric parameter (default {default!r})')
    if isinstance(default, int):
        d.integer_range = [IntegerRange(from_value=int(low), to_value=int(high), step=1)]
    else:
        d.floating_point_range = [FloatingPointRange(from_value=float(low),
                                                     to_value=float(high), step=0.0)]
    d.additional_constraints = f'from {low} to {high}'
    return d


def _entry(value: Sequence) -> Tuple[Any, str, bool]:
    """``(default, text, read_only)`` of a table entry with two or three fields."""
    if len(value) == 3:
        return value[0], value[1], bool(value[2])
    return value[0], value[1], False


def declare_table(node: Node, table: Mapping[str, Sequence],
                  limits: Optional[Mapping[str, Limits]] = None,
                  read_only: Iterable[str] = ()) -> List[str]:
    """
    Declare a node's parameter table with descriptors; report refused start-up values.

    Parameters already declared from the overrides (nodes created with
    ``automatically_declare_parameters_from_overrides``) are declared again with their
    descriptor and the same start-up value. An integer start-up value of a float parameter is
    taken as that float (also later, on ``ros2 param set``).

    Parameters
    ----------
    node : rclpy.node.Node
        The node.
    table : mapping
        Name to ``(default, description)`` or ``(default, description, read_only)``.
    limits : mapping, optional
        Name to inclusive ``(min, max)``.
    read_only : iterable of str, optional
        Names fixed at start-up (in addition to those the table marks).

    Returns
    -------
    list of str
        One message per refused start-up value (the parameter then has its default); each
        is also logged as an error.
    """
    limits = dict(limits or {})
    fixed = set(read_only)
    unknown = (set(limits) | fixed) - set(table)
    if unknown:
        raise ValueError(f'limits or read_only name undeclared parameters: {sorted(unknown)}')
    problems: List[str] = []
    floats = set()
    refused = _refusals(node)
    for name, value in table.items():
        default, text, ro = _entry(value)
        if isinstance(default, float):
            floats.add(name)
        desc = descriptor(default, text, limits.get(name), ro or name in fixed)
        if node.has_parameter(name):                # declared from the overrides
            node.undeclare_parameter(name)
        # rclpy has no public accessor of the start-up overrides; declare_parameter takes
        # the value from there and checks it against the default's type and the limits.
        overrides = getattr(node, '_parameter_overrides', {})
        start = overrides[name].value if name in overrides else None
        if isinstance(default, float) and isinstance(start, int) and \
                not isinstance(start, bool):
            start = float(start)
            overrides[name] = Parameter(name, Parameter.Type.DOUBLE, start)
        try:
            node.declare_parameter(name, default, desc)
        except (InvalidParameterValueException, InvalidParameterTypeException) as exc:
            reason = _reason(name, start, default, desc, exc)
            problems.append(reason)
            node.get_logger().error(reason)
            node.declare_parameter(name, default, descriptor(
                default, text, limits.get(name), ro or name in fixed), ignore_override=True)
            refused[name] = reason      # after the declaration, which counts as a set
    # rclpy concatenates what each pre-set callback returns: one callback per node.
    known = getattr(node, FLOATS_ATTRIBUTE, None)
    if known is None:
        known = set()
        setattr(node, FLOATS_ATTRIBUTE, known)
        node.add_pre_set_parameters_callback(
            lambda params: [_as_float(p) if p.name in known else p for p in params])
    known.update(floats)
    return problems


#: Parameters every rclpy node has (or takes from the command line) besides its table.
ROS_PARAMETERS = ('use_sim_time', 'start_type_description_service')


def refuse_unknown(node: Node, known: Iterable[str] = ()) -> List[str]:
    """
    Refuse start-up values of parameters the node does not have (a typo is not ignored).

    rclpy drops an override whose name was never declared without a word; a user who
    typed ``-p smaple_rate_Hz:=20000.0`` would run at the default. Call this after every
    declaration: each unknown name is logged as an error and returned, and it blocks the
    node's work like a refused value (:func:`pending_refusals`) until the node is restarted.

    Parameters
    ----------
    node : rclpy.node.Node
        The node, with all its parameters declared.
    known : iterable of str, optional
        Names the node has (prefixes ending in ``.`` match a group). A node that declares
        parameters from its overrides (``allow_undeclared_parameters``) must list them all;
        for the others, every declared parameter counts as known.

    Returns
    -------
    list of str
        One message per unknown name.
    """
    overrides = getattr(node, '_parameter_overrides', {})
    known = list(known)
    prefixes = tuple(k for k in known if k.endswith('.')) + ('qos_overrides.',)
    names = set(known) | set(ROS_PARAMETERS)
    # A node that declares its overrides itself has them all: only the list says which exist.
    declared_counts = not getattr(node, '_allow_undeclared_parameters', False)
    problems = []
    refused = _refusals(node)
    for name in sorted(overrides):
        if name in names or name.startswith(prefixes) or \
                (declared_counts and node.has_parameter(name)):
            continue
        reason = (f'parameter {name}: unknown to {node.get_name()} (a typo?); the start-up '
                  f'value {_short(overrides[name].value)} is not used; restart the node '
                  'without it (`--help` lists the parameters)')
        node.get_logger().error(reason)
        problems.append(reason)
        refused[name] = reason
    return problems


def refuse_choice(node: Node, name: str, choices: Sequence[str]) -> List[str]:
    """
    Refuse a start-up value of a string parameter outside its choices (default kept).

    Parameters
    ----------
    node : rclpy.node.Node
        The node, with ``name`` declared.
    name : str
        The parameter.
    choices : sequence of str
        The accepted values, the default first.

    Returns
    -------
    list of str
        The message, if refused (also logged and blocking like :func:`pending_refusals`).
    """
    value = node.get_parameter(name).value
    if value in choices:
        return []
    desc = node.describe_parameter(name)
    default = choices[0]            # the default comes first, by this module's convention
    read_only = desc.read_only
    if read_only:
        desc.read_only = False
        node.set_descriptor(name, desc)
    node.set_parameters([Parameter(name, value=default)])
    if read_only:
        desc.read_only = True
        node.set_descriptor(name, desc)
    reason = (f'parameter {name}: start-up value {_short(value)} refused: it must be one of '
              f'{", ".join(choices)}; the parameter keeps its default {default}')
    node.get_logger().error(reason)
    _refusals(node)[name] = reason
    return [reason]


def pending_refusals(node: Node) -> str:
    """
    The refused start-up values of a node that no valid value has replaced yet, or ''.

    A node does not start its work (arm, record) while this is not empty: the user set a
    value and got the default instead. Setting the parameter (to a valid value: an invalid
    one is refused) clears its entry; a read-only one needs a restart.

    Parameters
    ----------
    node : rclpy.node.Node
        A node whose parameters :func:`declare_table` declared.

    Returns
    -------
    str
        The messages, joined by ``'; '``.
    """
    return '; '.join(getattr(node, REFUSED_ATTRIBUTE, {}).values())


def _refusals(node: Node) -> dict:
    """The node's refused start-up values (created, with the callback that clears them)."""
    refused = getattr(node, REFUSED_ATTRIBUTE, None)
    if refused is None:
        refused = {}
        setattr(node, REFUSED_ATTRIBUTE, refused)

        def replaced(params: List[Parameter]) -> None:
            for p in params:
                refused.pop(p.name, None)

        node.add_post_set_parameters_callback(replaced)
    return refused


def _as_float(p: Parameter) -> Parameter:
    """An integer value of a float parameter as that float."""
    if p.type_ == Parameter.Type.INTEGER:
        return Parameter(p.name, Parameter.Type.DOUBLE, float(p.value))
    return p


def _reason(name: str, value: Any, default: Any, desc: ParameterDescriptor,
            exc: Exception) -> str:
    """The message for a refused start-up value."""
    if isinstance(exc, InvalidParameterTypeException) or \
            type(value) is not type(default):
        why = f'must be of type {type_name(default)}'
    else:
        why = f'must be {describe_limits(desc)}'
    return (f'parameter {name}: start-up value {value!r} refused: it {why}; the parameter '
            f'keeps its default {default!r}')


def type_name(default: Any) -> str:
    """
    The ROS parameter type of a table entry's default (``double``, ``string_array``...).

    Parameters
    ----------
    default : object or rclpy.parameter.Parameter.Type
        The default value, or the type of a parameter declared without one.

    Returns
    -------
    str
        The type as ``ros2 param describe`` names it, in lower case (``array`` for an
        empty or mixed list).
    """
    if isinstance(default, Parameter.Type):
        return default.name.lower()
    if isinstance(default, (list, tuple)):
        kinds = {_TYPE_NAMES.get(type(v)) for v in default}
        return f'{kinds.pop()}_array' if len(kinds) == 1 and None not in kinds else 'array'
    return _TYPE_NAMES.get(type(default), type(default).__name__)


def describe_limits(desc: ParameterDescriptor) -> str:
    """
    The limits of a descriptor as text (``'from 0.0 to 2.0'``), or ''.

    Parameters
    ----------
    desc : rcl_interfaces.msg.ParameterDescriptor
        The descriptor.

    Returns
    -------
    str
        Text for error messages and ``--help``.
    """
    for ranges in (desc.floating_point_range, desc.integer_range):
        if ranges:
            return f'from {ranges[0].from_value} to {ranges[0].to_value}'
    return ''


@dataclasses.dataclass(frozen=True)
class TableRow:
    """
    One parameter of a node's table, with its limits and whether it is fixed.

    Attributes
    ----------
    name : str
        The parameter's name.
    default : object or rclpy.parameter.Parameter.Type
        Its default (a ``Parameter.Type``: declared with that type and no value).
    text : str
        Its description, with the unit.
    limits : tuple, optional
        Inclusive ``(min, max)``, or None.
    read_only : bool
        Fixed at start-up.
    """

    name: str
    default: Any
    text: str
    limits: Optional[Limits]
    read_only: bool


def table_rows(table: Mapping[str, Sequence], limits: Optional[Mapping[str, Limits]] = None,
               read_only: Iterable[str] = ()) -> List[TableRow]:
    """
    The entries of a parameter table, in its order, with limits and read-only merged in.

    Parameters
    ----------
    table, limits, read_only
        As for :func:`declare_table`.

    Returns
    -------
    list of TableRow
        One per parameter.
    """
    limits = dict(limits or {})
    fixed = set(read_only)
    rows = []
    for pname, value in table.items():
        default, text, ro = _entry(value)
        rows.append(TableRow(pname, default, text, limits.get(pname), ro or pname in fixed))
    return rows


#: A parameter group: what it is, its table (names with a placeholder) and its limits.
Group = Tuple[str, Mapping[str, Sequence], Mapping[str, Limits]]


@dataclasses.dataclass(frozen=True)
class NodeTable:
    """
    Everything a node module says about its parameters (see the module docstring).

    Attributes
    ----------
    doc : str
        The module's docstring (purpose, topics, services).
    table : mapping
        ``PARAMETERS``.
    limits : mapping
        ``LIMITS``.
    read_only : tuple of str
        ``READ_ONLY``.
    groups : mapping
        ``PARAMETER_GROUPS``: title to ``(text, table, limits)``.
    extra : str
        ``HELP_EXTRA``.
    """

    doc: str
    table: Mapping[str, Sequence]
    limits: Mapping[str, Limits]
    read_only: Tuple[str, ...]
    groups: Mapping[str, Group]
    extra: str

    def rows(self) -> List[TableRow]:
        """
        The table's parameters (:func:`table_rows`).

        Returns
        -------
        list of TableRow
            One per entry of ``PARAMETERS``.
        """
        return table_rows(self.table, self.limits, self.read_only)


def node_table(module: Any) -> NodeTable:
    """
    Gather a node module's parameter tables (all optional; absent: empty).

    Parameters
    ----------
    module : module or None
        A node module (``emfc_ros.nodes.<name>``).

    Returns
    -------
    NodeTable
        Its docstring, ``PARAMETERS``, ``LIMITS``, ``READ_ONLY``, ``PARAMETER_GROUPS`` and
        ``HELP_EXTRA``.
    """
    return NodeTable(getattr(module, '__doc__', '') or '',
                     dict(getattr(module, 'PARAMETERS', {}) or {}),
                     dict(getattr(module, 'LIMITS', {}) or {}),
                     tuple(getattr(module, 'READ_ONLY', ()) or ()),
                     dict(getattr(module, 'PARAMETER_GROUPS', {}) or {}),
                     getattr(module, 'HELP_EXTRA', '') or '')


def help_text(name: str, doc: str, table: Mapping[str, Sequence],
              limits: Optional[Mapping[str, Limits]] = None,
              read_only: Iterable[str] = (), extra: str = '',
              groups: Optional[Mapping[str, Group]] = None) -> str:
    """
    The ``--help`` text of a node executable.

    Parameters
    ----------
    name : str
        Node name.
    doc : str
        The node module's docstring (purpose, topics, services).
    table, limits, read_only
        As for :func:`declare_table`.
    extra : str, optional
        Further parameters not in the table (free text).
    groups : mapping, optional
        Parameter groups: title to ``(text, table, limits)`` (:class:`NodeTable`).

    Returns
    -------
    str
        Usage, the docstring, and one entry per parameter: default, limits, fixed at
        start-up, description.
    """
    lines = [f'usage: {name} [--help] [--ros-args -p NAME:=VALUE ... '
             '[--params-file FILE] [-r FROM:=TO] ...]', '']
    lines += [line.rstrip() for line in (doc or '').strip().splitlines()]
    lines += ['', 'Parameters (name: type, default; limits; description):', '']
    lines += _help_entries(table_rows(table, limits, read_only))
    for title, (text, group, group_limits) in (groups or {}).items():
        lines += [''] + _wrap(f'{title}: {text}', '  ')
        lines += _help_entries(table_rows(group, group_limits))
    if extra:
        lines += [''] + _wrap(extra, '  ')
    lines += [''] + _wrap(f'Start it with `ros2 run emfc_ros {name} --ros-args ...`; `ros2 '
                          f'param describe /<namespace>/{name} <parameter>` shows the same '
                          'limits on a running node.', '')
    return '\n'.join(lines) + '\n'


def _help_entries(rows: Sequence[TableRow]) -> List[str]:
    """The ``--help`` lines of parameters: a head line each, the description wrapped."""
    lines = []
    for row in rows:
        shown = row.default if not isinstance(row.default, Parameter.Type) else 'unset'
        head = f'  {row.name}: {type_name(row.default)}, default {shown!r}'
        if row.limits is not None:
            head += f'; from {row.limits[0]} to {row.limits[1]}'
        if row.read_only:
            head += '; read-only (fixed at start-up)'
        lines.append(head)
        lines += _wrap(row.text, '      ')
    return lines


def _wrap(text: str, indent: str, width: int = 92) -> List[str]:
    """Wrap ``text`` at word boundaries with ``indent``."""
    out, line = [], ''
    for word in text.split():
        if line and len(indent) + len(line) + 1 + len(word) > width:
            out.append(indent + line)
            line = word
        else:
            line = f'{line} {word}' if line else word
    if line:
        out.append(indent + line)
    return out


def startup_line(node: Node, module: Any) -> str:
    """
    The one start-up log line of a node: its key parameters and those set at start-up.

    Parameters
    ----------
    node : rclpy.node.Node
        The node, constructed.
    module : module or None
        The node's module: ``PARAMETERS`` (the table) and ``STARTUP_KEYS`` (the parameters
        always shown: mode, rates, files), both optional.

    Returns
    -------
    str
        ``started as /ns/name: key=value, ...; set at start-up: name=value, ...``.
    """
    table = getattr(module, 'PARAMETERS', {}) or {}
    keys = [k for k in getattr(module, 'STARTUP_KEYS', ()) if k in table]
    changed = []
    for pname, entry in table.items():
        if pname in keys:
            continue
        value = _value_of(node, pname)
        if value is not None and value != _entry(entry)[0]:
            changed.append(pname)
    parts = [f'{k}={_short(_value_of(node, k))}' for k in keys]
    line = f'started as {node.get_fully_qualified_name()}'
    if parts:
        line += ': ' + ', '.join(parts)
    if changed:
        line += '; set at start-up: ' + ', '.join(
            f'{k}={_short(_value_of(node, k))}' for k in changed)
    return line


def _value_of(node: Node, name: str) -> Any:
    """A parameter's value, or None if it is not declared or not set."""
    try:
        return node.get_parameter(name).value
    except Exception:       # undeclared, or declared with a type and no value
        return None


def _short(value: Any, width: int = 60) -> str:
    """``repr`` of a value, cut to ``width`` characters."""
    text = repr(value)
    return text if len(text) <= width else text[:width - 3] + '...'
