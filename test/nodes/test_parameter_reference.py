"""
docs/parameters.md is the rendering of the nodes' own parameter tables, and says what they say.

The page must equal :func:`emfc_ros.nodes.param_reference.render` byte for byte (the failure
prints the command that regenerates it); every node executable of setup.py with a
``PARAMETERS`` table has a section; read back with a parser of its own, each row carries its
table's default (as YAML), limits, read-only flag and the units of its description.
"""

import importlib
from pathlib import Path
import re

from rclpy.parameter import Parameter
import yaml

from emfc_ros.nodes import param_reference
from emfc_ros.nodes.params import node_table, table_rows

REPO = Path(__file__).resolve().parents[2]
PAGE_PATH = REPO / 'docs' / 'parameters.md'
PAGE = PAGE_PATH.read_text()
SETUP = (REPO / 'setup.py').read_text()
NODES = re.findall(r"'(\w+)': 'emfc_ros\.nodes\.(\w+):main'", SETUP)
#: A unit in a description: ``[Hz]``, ``[m rms]``, ``[N/sqrt(s)]`` (not ``[t_k, t_k+1)``).
UNIT = re.compile(r'\[[^\[\]_,;*<&|]+\]')
#: A name ending in an SI unit suffix (``rate_Hz``; not a ratio such as ``units_per_V``).
SUFFIX = re.compile(r'(?<!_per)_(Hz|s|V|kg|m|A|B|deg|N|rad)$')
SUFFIX_UNIT = {'B': 'bytes'}


def _sections(text):
    """Node name to the body of its ``## <name>`` section."""
    parts = re.split(r'^## (\w+)\n', text, flags=re.M)
    return dict(zip(parts[1::2], parts[2::2]))


def _cells(line):
    r"""The cells of a table line, ``\|`` kept inside a cell."""
    cells = re.split(r'(?<!\\)\|', line.strip())[1:-1]
    return [c.strip() for c in cells]


def _rows(section):
    """Parameter name to its cells (type, default, limits, read-only, meaning)."""
    rows = {}
    for line in section.splitlines():
        if not line.startswith('| `'):
            continue
        cells = _cells(line)
        assert len(cells) == 6, line
        name = cells[0].strip('`')
        assert name not in rows, f'{name} twice in one section'
        rows[name] = cells[1:]
    return rows


def _code(cell):
    """The text of a code span cell."""
    assert cell.startswith('`') and cell.endswith('`'), cell
    return cell.strip('`').strip().replace('\\|', '|')


def _tables(name):
    return node_table(importlib.import_module(f'emfc_ros.nodes.{name}'))


def test_the_page_is_the_rendering_of_the_tables():
    rendered = param_reference.render()
    assert PAGE == rendered, (
        'docs/parameters.md is stale: regenerate it from the checkout with\n    '
        f'{param_reference.REGENERATE}')
    assert param_reference.render() == rendered        # deterministic
    assert param_reference.REGENERATE in PAGE


def test_every_node_with_a_table_has_a_section():
    assert len(NODES) >= 7
    sections = _sections(PAGE)
    with_table = [node for node, module in NODES
                  if getattr(importlib.import_module(f'emfc_ros.nodes.{module}'),
                             'PARAMETERS', None)]
    assert sorted(with_table) == sorted(param_reference.NODES)
    assert sorted(sections) == sorted(with_table)
    for node in with_table:
        assert f'[{node}](#{node})' in PAGE             # the link list at the top


def test_known_defaults_appear_as_the_tables_give_them():
    from emfc_ros.nodes import daq_bridge, signal_generator
    sections = _sections(PAGE)
    bridge = _rows(sections['daq_bridge'])
    generator = _rows(sections['signal_generator'])
    assert bridge['backend'][1] == f"`{daq_bridge.PARAMETERS['backend'][0]}`" == '`sim`'
    assert generator['pacing'][1] == f"`{signal_generator.PARAMETERS['pacing'][0]}`" \
        == '`wall`'
    assert bridge['backend'][3] == 'yes' and generator['pacing'][3] == 'no'
    assert bridge['sample_rate_Hz'][:3] == ['double', '`10000.0`', '0.0 to 10000000.0']
    assert bridge['outputs'][:2] == ['string_array', '`[coil_V, load_changer_V]`']
    assert bridge['input_units'][:2] == ['string_array', 'unset']
    # every back-end option of the registry, and one group row per generator field
    from emfc_ros.core.device import registry
    assert set(registry.parameter_table()) <= set(bridge)
    from emfc_ros.core.device.bridge_settings import FUNCGEN_FIELDS
    assert {f'funcgen.<output>.{f}' for f in FUNCGEN_FIELDS} <= set(bridge)
    assert bridge['funcgen.<output>.waveform'][1] == "`'off'`"     # YAML would read a bool


def _node_rows():
    """Per node: its page rows (name to cells) and its table entries (groups included)."""
    sections = _sections(PAGE)
    for node in param_reference.NODES:
        tables = _tables(node)
        entries = tables.rows() + [r for _, group, limits in tables.groups.values()
                                   for r in table_rows(group, limits)]
        yield node, _rows(sections[node]), entries


def test_every_row_reads_back_as_its_table_entry():
    checked = 0
    for node, rows, entries in _node_rows():
        assert sorted(rows) == sorted(r.name for r in entries), node
        for entry in entries:
            kind, default, limits, read_only, _ = rows[entry.name]
            if isinstance(entry.default, Parameter.Type):
                assert default == 'unset' and kind == entry.default.name.lower()
            else:
                value = entry.default
                value = list(value) if isinstance(value, tuple) else value
                assert yaml.safe_load(_code(default)) == value, (node, entry.name)
                assert type(yaml.safe_load(_code(default))) is type(value), entry.name
            if entry.limits is None:
                assert limits == '', entry.name
            else:
                low, high = (yaml.safe_load(v) for v in limits.split(' to '))
                assert (low, high) == tuple(entry.limits), entry.name
            assert read_only == ('yes' if entry.read_only else 'no'), entry.name
            checked += 1
    assert checked >= 150


def test_descriptions_keep_their_units():
    units = 0
    for node, rows, entries in _node_rows():
        for entry in entries:
            meaning = rows[entry.name][4]
            for unit in UNIT.findall(entry.text):
                assert unit in meaning, (node, entry.name, unit)
                units += 1
            suffix = SUFFIX.search(entry.name)
            if suffix:      # a name with a unit suffix states that unit in brackets
                unit = SUFFIX_UNIT.get(suffix.group(1), suffix.group(1))
                assert re.search(rf'\[[^\]]*\b{re.escape(unit)}\b[^\]]*\]', meaning), \
                    (node, entry.name)
    assert units >= 90
    bridge = _rows(_sections(PAGE)['daq_bridge'])
    assert '[Hz]' in bridge['sample_rate_Hz'][4] and '[unit rms]' in bridge['input_noise_rms'][4]


def test_cells_escape_markdown():
    assert param_reference.escape_text('a | b') == 'a \\| b'
    assert param_reference.escape_text('<topic>/x, 2**40') == '&lt;topic>/x, 2\\*\\*40'
    assert param_reference.escape_text('plain `a|b` mapping') == 'plain `a\\|b` mapping'
    assert param_reference.escape_text('sample_rate_Hz, the _V suffix') == \
        'sample_rate_Hz, the \\_V suffix'
    assert param_reference.code('x|y') == '`x\\|y`'
    assert param_reference.yaml_value(('ai0', 'ai1')) == '[ai0, ai1]'
    assert param_reference.yaml_value(1e-6) == '1.0e-06'
    assert param_reference.yaml_value('') == "''"
    assert param_reference.yaml_value(True) == 'true'
    # no raw pipe splits a row: every table line of the page has exactly the six cells
    for line in PAGE.splitlines():
        if line.startswith('| `'):
            assert len(_cells(line)) == 6, line
