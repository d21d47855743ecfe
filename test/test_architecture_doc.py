"""
docs/architecture.md tells the truth where it can be checked from the sources.

Every path it writes in backticks exists (``emfc_ros/...``, ``core/...`` and ``nodes/...``
under ``emfc_ros``, the checkout's folders); every ``emfc-*`` command is a console script of
setup.py; every node it names has a module in ``emfc_ros/nodes``, and the figure shows each
node executable; a class named beside its module is defined there; every topic of the data
path table is in the source of each node the table says runs that stage (quoted, as
a name in code or in the module's docstring).
"""

from pathlib import Path
import re
from typing import List

REPO = Path(__file__).resolve().parents[1]
PAGE = REPO / 'docs' / 'architecture.md'
SETUP = (REPO / 'setup.py').read_text()
SCRIPTS = set(re.findall(r"'(emfc-[a-z-]+)': 'emfc_ros", SETUP))
NODES = set(re.findall(r"'(\w+)': 'emfc_ros\.nodes\.\w+:main'", SETUP))
SPAN = re.compile(r'`([^`\n]+)`')
#: Where a backticked path starts: under emfc_ros, or a folder of the checkout.
PACKAGE_ROOTS = ('core/', 'nodes/', 'cli/')
CHECKOUT_ROOTS = ('emfc_ros/', 'test/', 'launch/', 'config/', 'bench/', 'docs/', 'tools/',
                  'lib_wrappers/')
TOPIC = re.compile(r'~?/?[a-z_]+(/[a-z_]+)*')


def missing_paths(text: str) -> List[str]:
    """The backticked paths of a text that do not exist in the checkout."""
    missing = []
    for span in SPAN.findall(text):
        if span.startswith(PACKAGE_ROOTS):
            path = REPO / 'emfc_ros' / span
        elif span.startswith(CHECKOUT_ROOTS):
            path = REPO / span
        else:
            continue
        if not path.exists():
            missing.append(span)
    return missing


def unknown_scripts(text: str) -> List[str]:
    """The backticked ``emfc-*`` commands of a text that setup.py does not install."""
    words = [span.split()[0] for span in SPAN.findall(text)]
    return [w for w in words if w.startswith('emfc-') and w not in SCRIPTS]


def named_nodes(text: str) -> List[str]:
    """Nodes the text names: "the `x` node" and the runners of the data path table."""
    names = re.findall(r'`(\w+)`\s+node\b', text)
    for row in table_rows(text):
        names += [s for s in SPAN.findall(row[1]) if not s.startswith('emfc-')]
    return names


def table_rows(text: str) -> List[List[str]]:
    """The body rows of the data path table, as cells."""
    section = text.split('## The data path', 1)[1].split('\n## ', 1)[0]
    rows = [[c.strip() for c in line.strip().strip('|').split('|')]
            for line in section.splitlines() if line.startswith('|')]
    return [r for r in rows[2:] if len(r) == 5]


def test_the_page_exists_is_one_page_and_is_linked():
    text = PAGE.read_text()
    assert 120 <= len(text.splitlines()) <= 300
    assert 'docs/architecture.md' in (REPO / 'README.md').read_text()
    assert not re.search(r'^#+ .*\bissue', text, re.M | re.I), 'issue numbers in headings'


def test_every_path_exists_and_the_checker_sees_a_bogus_one():
    assert missing_paths(PAGE.read_text()) == []
    assert missing_paths('`core/sim/no_such_session.py` `emfc_ros/nodes/gone.py`') == [
        'core/sim/no_such_session.py', 'emfc_ros/nodes/gone.py']


def test_every_command_is_a_console_script():
    assert unknown_scripts(PAGE.read_text()) == []
    assert unknown_scripts('run `emfc-no-such --help`') == ['emfc-no-such']


def test_every_node_named_has_a_module_and_the_figure_shows_them_all():
    text = PAGE.read_text()
    names = named_nodes(text)
    assert names and sorted(n for n in set(names) if n not in NODES) == []
    assert [n for n in names if not (REPO / 'emfc_ros' / 'nodes' / f'{n}.py').exists()] == []
    figure = text.split('```text\n', 1)[1].split('```', 1)[0]
    assert sorted(n for n in NODES if n not in figure) == []


def test_a_class_named_beside_its_module_is_defined_there():
    pairs = re.findall(r'`([A-Z]\w+)`\s+\(`((?:core|nodes)/[\w/]+\.py)`\)', PAGE.read_text())
    assert pairs
    for name, module in pairs:
        source = (REPO / 'emfc_ros' / module).read_text()
        assert re.search(rf'^(class {name}\b|{name}\s*[:=])', source, re.M), (name, module)


def test_every_topic_of_the_data_path_is_in_the_nodes_that_run_the_stage():
    rows = table_rows(PAGE.read_text())
    assert len(rows) >= 6
    checked = 0
    for stage, runners, inputs, outputs, _ in rows:
        nodes = [s for s in SPAN.findall(runners) if s in NODES]
        topics = [s for s in SPAN.findall(inputs + outputs) if TOPIC.fullmatch(s)]
        for node in nodes:
            source = (REPO / 'emfc_ros' / 'nodes' / f'{node}.py').read_text()
            absent = [t for t in topics
                      if not re.search(rf'[`\'"]{re.escape(t)}[`\'"]', source)]
            assert absent == [], f'{stage}: {node} has no {absent}'
            checked += len(topics)
    assert checked >= 20
