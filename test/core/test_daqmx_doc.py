"""docs/daqmx.md's wiring tables are the wiring the code uses, and its paths exist."""

from pathlib import Path
import re

from emfc_ros.core.device.daqmx_wiring import DEFAULT_AI_WIRING, DEFAULT_AO_WIRING

REPO = Path(__file__).resolve().parents[2]
PAGE = (REPO / 'docs' / 'daqmx.md').read_text()
ROW = re.compile(r'^\| `(\w+)` \| (a[io]\d) \|(.*)\|$', re.MULTILINE)


def _rows():
    return [(name, terminal, [c.strip() for c in rest.split('|')])
            for name, terminal, rest in ROW.findall(PAGE)]


def test_the_input_table_is_the_default_wiring():
    inputs = [(n, t, cells) for n, t, cells in _rows() if t.startswith('ai')]
    assert len(inputs) == len(DEFAULT_AI_WIRING)
    for (name, terminal, cells), wire in zip(inputs, DEFAULT_AI_WIRING):
        unit, per_V, range_V, signal = cells
        assert (name, terminal, unit, signal) == (wire.name, wire.terminal, wire.unit,
                                                  wire.signal)
        assert float(per_V) == wire.units_per_V
        assert float(range_V) == wire.range_V


def test_the_output_table_is_the_default_wiring():
    outputs = [(n, t) for n, t, _ in _rows() if t.startswith('ao')]
    assert tuple(outputs) == DEFAULT_AO_WIRING


def test_every_path_the_page_names_exists():
    spans = re.findall(r'`((?:emfc_ros|test|docs|config)/[^`\s]+)`', PAGE)
    assert spans
    missing = [s for s in spans if not (REPO / s).exists()]
    assert not missing, missing
