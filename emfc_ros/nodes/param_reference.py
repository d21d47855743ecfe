"""
The parameter reference of every node, ``docs/parameters.md``, rendered from the nodes' tables.

Each node module's ``PARAMETERS``, ``LIMITS``, ``READ_ONLY``, ``PARAMETER_GROUPS`` and
``HELP_EXTRA``, gathered by :func:`emfc_ros.nodes.params.node_table` as for ``--help``, become
one section per node (``## <node>``, so that other pages link ``parameters.md#<node>``) with
a table ``| parameter | type | default | limits | read-only | meaning |``. Defaults are
written as a params file or ``-p name:=value`` takes them (YAML); the page depends on
nothing but the tables, so the same sources render the same bytes.

Regenerate the page from the checkout, with the virtual environment's python::

    .venv/bin/python -m emfc_ros.nodes.param_reference > docs/parameters.md

``test/nodes/test_parameter_reference.py`` fails while the page differs from the rendering.
"""

from __future__ import annotations

import importlib
import re
import sys
from typing import Any, List, Optional, Sequence, Tuple

from rclpy.parameter import Parameter
import yaml

from emfc_ros.nodes.params import (Limits, node_table, NodeTable, table_rows, TableRow,
                                   type_name)

#: The node executables (``ros2 run emfc_ros <name>``), in the page's order; the module of
#: each is ``emfc_ros.nodes.<name>``.
NODES = ('signal_generator', 'plant_simulator', 'recorder', 'daq_bridge', 'identifier',
         'position_controller', 'weighing')
#: The command that writes the page (from the checkout).
REGENERATE = '.venv/bin/python -m emfc_ros.nodes.param_reference > docs/parameters.md'
HEADER = ('parameter', 'type', 'default', 'limits', 'read-only', 'meaning')
_CODE_SPAN = re.compile(r'(`+)(.+?)\1')
#: An underscore that Markdown could take for emphasis (not inside a word).
_LOOSE_UNDERSCORE = re.compile(r'(?<![A-Za-z0-9])_|_(?![A-Za-z0-9])')


def yaml_value(value: Any) -> str:
    """
    A default or a limit as a params file or ``-p name:=value`` takes it (flow YAML).

    Parameters
    ----------
    value : object
        A parameter value: bool, int, float, str, or a list or tuple of them.

    Returns
    -------
    str
        One line: ``true``, ``10000.0``, ``1.0e-06``, ``''``, ``'off'`` (quoted where YAML
        would read another type), ``[coil_V, load_changer_V]``.
    """
    if isinstance(value, tuple):
        value = list(value)
    text = yaml.safe_dump(value, default_flow_style=True, width=sys.maxsize)
    if text.endswith('\n...\n'):
        text = text[:-len('...\n')]
    return text.strip()


def escape_text(text: str) -> str:
    r"""
    Free text for a Markdown table cell or paragraph: shown as written.

    Code spans are kept (only ``|`` is escaped in them); outside them ``\``, ``*``, loose
    ``_``, ``<``, ``&`` and ``|`` are escaped, and line breaks become spaces.

    Parameters
    ----------
    text : str
        A description.

    Returns
    -------
    str
        The Markdown.
    """
    out, start = [], 0
    text = ' '.join(text.split())
    for match in _CODE_SPAN.finditer(text):
        out.append(_escape_plain(text[start:match.start()]))
        out.append(match.group(0).replace('|', '\\|'))
        start = match.end()
    out.append(_escape_plain(text[start:]))
    return ''.join(out)


def _escape_plain(text: str) -> str:
    """Escape the Markdown of text outside code spans."""
    text = text.replace('\\', '\\\\').replace('&', '&amp;').replace('<', '&lt;')
    text = text.replace('*', '\\*').replace('|', '\\|')
    return _LOOSE_UNDERSCORE.sub(r'\\_', text)


def code(text: str) -> str:
    """
    Text as a Markdown code span for a table cell (``|`` escaped).

    Parameters
    ----------
    text : str
        One line.

    Returns
    -------
    str
        The span, with a longer fence where the text holds backticks.
    """
    fence = '`' * (max((len(r) for r in re.findall('`+', text)), default=0) + 1)
    pad = ' ' if fence != '`' else ''
    return f'{fence}{pad}{text}{pad}{fence}'.replace('|', '\\|')


def default_cell(default: Any) -> str:
    """
    The default column: the YAML value as code, or ``unset`` (declared with a type only).

    Parameters
    ----------
    default : object or rclpy.parameter.Parameter.Type
        A table entry's default.

    Returns
    -------
    str
        The cell.
    """
    if isinstance(default, Parameter.Type):
        return 'unset'
    return code(yaml_value(default))


def limits_cell(limits: Optional[Limits]) -> str:
    """
    The limits column: ``min to max`` (inclusive), or empty.

    Parameters
    ----------
    limits : tuple, optional
        Inclusive ``(min, max)``.

    Returns
    -------
    str
        The cell.
    """
    if limits is None:
        return ''
    return f'{yaml_value(limits[0])} to {yaml_value(limits[1])}'


def table_lines(rows: Sequence[TableRow]) -> List[str]:
    """
    A Markdown table of parameters.

    Parameters
    ----------
    rows : sequence of TableRow
        The parameters (:func:`emfc_ros.nodes.params.table_rows`).

    Returns
    -------
    list of str
        Header, separator, one line per parameter.
    """
    lines = ['| ' + ' | '.join(HEADER) + ' |', '|' + '---|' * len(HEADER)]
    for row in rows:
        cells = (code(row.name), type_name(row.default), default_cell(row.default),
                 limits_cell(row.limits), 'yes' if row.read_only else 'no',
                 escape_text(row.text))
        lines.append('| ' + ' | '.join(cells) + ' |')
    return lines


def purpose(doc: str) -> str:
    """
    The first line of a node module's docstring, without the ``The <node> node:`` prefix.

    Parameters
    ----------
    doc : str
        The docstring.

    Returns
    -------
    str
        One sentence.
    """
    lines = doc.strip().splitlines()
    first = lines[0].strip() if lines else ''
    return re.sub(r'^The \w+ node:\s*', '', first)


def node_section(name: str, tables: NodeTable) -> List[str]:
    """
    The section of one node: heading, purpose, the table, its groups and further parameters.

    Parameters
    ----------
    name : str
        The node executable.
    tables : NodeTable
        Its tables (:func:`emfc_ros.nodes.params.node_table`).

    Returns
    -------
    list of str
        Markdown lines, without a trailing blank line.
    """
    first = purpose(tables.doc)
    lines = [f'## {name}', '']
    if first:
        lines += [escape_text(first[0].upper() + first[1:]), '']
    lines += table_lines(tables.rows())
    for title, (text, group, group_limits) in tables.groups.items():
        lines += ['', f'{code(title)}: {escape_text(text)}.', '']
        lines += table_lines(table_rows(group, group_limits))
    if tables.extra:
        lines += ['', f'Not in the table: {escape_text(tables.extra)}']
    return lines


def node_tables(names: Sequence[str] = NODES) -> List[Tuple[str, NodeTable]]:
    """
    The tables of the node modules (``emfc_ros.nodes.<name>``, imported).

    Parameters
    ----------
    names : sequence of str
        Node executables.

    Returns
    -------
    list of (str, NodeTable)
        One per node with a ``PARAMETERS`` table, in the given order.
    """
    found = []
    for name in names:
        module = importlib.import_module(f'emfc_ros.nodes.{name}')
        if getattr(module, 'PARAMETERS', None):
            found.append((name, node_table(module)))
    return found


def render(names: Sequence[str] = NODES) -> str:
    """
    The whole page ``docs/parameters.md``.

    Parameters
    ----------
    names : sequence of str
        Node executables, in the page's order.

    Returns
    -------
    str
        Markdown, ending with one newline.
    """
    nodes = node_tables(names)
    lines = [
        '# Node parameters',
        '',
        "Every parameter of every node, generated from the nodes' own parameter tables (the",
        'ones `--help` prints) by `emfc_ros/nodes/param_reference.py`: do not edit this page',
        'by hand. After changing a table, regenerate the page from the checkout with',
        f'`{REGENERATE}`;',
        '`test/nodes/test_parameter_reference.py` fails while it is stale.',
        '',
        'Give parameters at start-up with `--ros-args -p name:=value` or a params file',
        '(`--params-file`). **type** is the ROS parameter type; **default** is the value as',
        'either takes it (YAML; `unset`: declared with its type and no value). **limits** are',
        'inclusive: `ros2 param describe` shows them, `ros2 param set` outside them is refused',
        'at once, and a start-up value outside them is refused too: the node keeps the default',
        'and reports the error. A **read-only** parameter is fixed at start-up. Units are in',
        'the names and in brackets in **meaning**. `ros2 run emfc_ros <node> --help` prints',
        'the same tables.',
        '',
        'Nodes: ' + ', '.join(f'[{name}](#{name})' for name, _ in nodes) + '.',
    ]
    for name, tables in nodes:
        lines += [''] + node_section(name, tables)
    return '\n'.join(lines) + '\n'


def main() -> int:
    """
    Print the page (``python -m emfc_ros.nodes.param_reference > docs/parameters.md``).

    Returns
    -------
    int
        Exit code 0.
    """
    sys.stdout.write(render())
    return 0


if __name__ == '__main__':
    sys.exit(main())
