"""
A README line is a test: every command the user docs show is run by a named test, or listed.

The user docs are README.md and its guide pages (``readme_lines.GUIDE_PAGES``).

``test/readme_lines.py`` extracts the commands (fenced shell blocks; inline ``emfc-*`` and
``tools/`` commands); ``test/readme_commands.yaml`` maps each, normalised, to the tests that
run it as a user types it (``covered``), or says why it cannot run here and which test
stands in (``not_here``). This test fails when a README command has no entry (listing the
lines, ready to paste), when an entry names a test that does not exist, and when an entry's
command is no longer in the README. The checks run on any text, so they are tested here
against made-up READMEs and registries too.
"""

import ast
from pathlib import Path
import re
from typing import Dict, List, Mapping

import pytest
import yaml

import readme_lines

REPO = Path(__file__).resolve().parents[1]
REGISTRY = REPO / 'test' / 'readme_commands.yaml'
TEST_ID = re.compile(r'^(test/[\w/]+\.py)::(\w+)(\[[^\]]*\])?$')


def load_registry(path: Path = REGISTRY) -> Dict[str, dict]:
    """
    The registry as command to ``{'tests': [...]}`` or ``{'not_here': ..., 'stand_in': [...]}``.

    Raises
    ------
    ValueError
        If an entry is malformed or a command is listed twice.
    """
    doc = yaml.safe_load(path.read_text())
    if set(doc) != {'covered', 'not_here'}:
        raise ValueError(f'{path.name}: top-level keys must be covered and not_here')
    out = {}
    for command, tests in (doc['covered'] or {}).items():
        if not isinstance(tests, list) or not tests:
            raise ValueError(f'{command!r}: covered needs a list of tests')
        out[command] = {'tests': tests}
    for command, entry in (doc['not_here'] or {}).items():
        if command in out:
            raise ValueError(f'{command!r} is both covered and not_here')
        if not isinstance(entry, dict) or set(entry) != {'not_here', 'stand_in'} or \
                not str(entry['not_here']).strip() or not isinstance(entry['stand_in'], list):
            raise ValueError(f'{command!r}: not_here needs {{not_here: reason, stand_in: '
                             '[tests]}}')
        out[command] = {'not_here': entry['not_here'], 'tests': entry['stand_in']}
    return out


def defined_tests(path: Path) -> set:
    """Test functions of a test file (module level and in classes)."""
    tree = ast.parse(path.read_text(), str(path))
    return {node.name for node in ast.walk(tree)
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
            and node.name.startswith('test')}


def missing_tests(registry: Mapping[str, dict], root: Path = REPO) -> List[str]:
    """Every test id of the registry that names no existing test function."""
    out = []
    for command, entry in registry.items():
        for test_id in entry['tests']:
            match = TEST_ID.match(str(test_id))
            if not match:
                out.append(f'{command!r}: {test_id!r} is not test/<path>.py::<test_name>')
                continue
            path = root / match.group(1)
            if not path.is_file() or match.group(2) not in defined_tests(path):
                out.append(f'{command!r}: {test_id} does not exist')
    return out


def uncovered(commands: List[str], registry: Mapping[str, dict]) -> List[str]:
    """README commands without a registry entry, as lines to paste into the registry."""
    return [f'"{c}": [test/...::test_...]' for c in commands if c not in registry]


def stale(commands: List[str], registry: Mapping[str, dict]) -> List[str]:
    """Registry commands the README no longer shows."""
    return [c for c in registry if c not in set(commands)]


def test_every_readme_command_has_a_test_or_a_reason():
    commands = [c for _, c in readme_lines.readme_commands()]
    registry = load_registry()
    lines = uncovered(commands, registry)
    assert lines == [], ('README commands without a test; add to test/readme_commands.yaml:\n'
                         + '\n'.join(lines))
    assert stale(commands, registry) == [], 'registry entries no longer in the user docs'
    assert missing_tests(registry) == []


def test_the_registry_reads_back_every_line_of_the_readme_blocks():
    # The extraction finds what a reader sees: the first two commands, a continued line,
    # an indented block, table cells and prose spans.
    commands = [c for _, c in readme_lines.readme_commands()]
    assert commands[:2] == ['./tools/experiment.sh', './tools/test.sh']
    assert any(c.startswith('ros2 run emfc_ros recorder --ros-args -r __ns:=/emfc -p '
                            'use_sim_time:=true') and c.endswith('/clock]') for c in commands)
    assert 'ros2 param set /plant_simulator load_mass_kg 0.05' in commands      # indented
    assert 'emfc-simulate EXCITATION -o OUT' in commands                        # table
    assert 'emfc-device-emulator --control-crossover-Hz 130' in commands         # prose
    assert not any(c.startswith('emfc-*') or c.startswith('emfc-<') for c in commands)
    registry = load_registry()
    assert all(entry['not_here'] for entry in registry.values() if 'not_here' in entry)


README = """# x

```bash
./tools/experiment.sh   # main job
emfc-demo --out d \\
  --timeout 5
```

```yaml
run: {}
```

  ```bash
  ros2 run emfc_ros weighing
  ```

| command | does |
|---|---|
| `emfc-bag-info BAG` | inspect |

`emfc-*` names, `emfc-<name>`, `tools/bench.sh bench_signals`.
"""


def write_registry(path: Path, covered: dict, not_here: dict) -> Path:
    path.write_text(yaml.safe_dump({'covered': covered, 'not_here': not_here}))
    return path


def test_the_checks_fail_both_ways(tmp_path):
    commands = [c for _, c in readme_lines.readme_commands(README)]
    assert commands == ['./tools/experiment.sh', 'emfc-demo --out d --timeout 5',
                        'ros2 run emfc_ros weighing', 'emfc-bag-info BAG',
                        './tools/bench.sh bench_signals']
    real = 'test/test_readme_commands.py::test_the_checks_fail_both_ways'
    registry = load_registry(write_registry(tmp_path / 'r.yaml', {
        './tools/experiment.sh': [real], 'emfc-demo --out d --timeout 5': [real],
        'ros2 run emfc_ros weighing': ['test/test_readme_commands.py::test_not_there'],
        'emfc-bag-info BAG': ['test/nowhere.py::test_x'],
        'emfc-old --flag': [real + '[param]']},
        {'./tools/bench.sh bench_signals': {'not_here': 'slow', 'stand_in': []}}))
    # a new README line without an entry
    assert uncovered(commands + ['emfc-weigh --new'], registry) == [
        '"emfc-weigh --new": [test/...::test_...]']
    # entries naming tests that do not exist (missing function, missing file)
    assert sorted(missing_tests(registry)) == [
        "'emfc-bag-info BAG': test/nowhere.py::test_x does not exist",
        "'ros2 run emfc_ros weighing': test/test_readme_commands.py::test_not_there does not "
        'exist']
    # an entry whose command left the README
    assert stale(commands, registry) == ['emfc-old --flag']
    with pytest.raises(ValueError, match='not_here needs'):
        load_registry(write_registry(tmp_path / 'b.yaml', {}, {'x': {'not_here': ''}}))
    with pytest.raises(ValueError, match='covered needs a list'):
        load_registry(write_registry(tmp_path / 'c.yaml', {'x': []}, {}))
