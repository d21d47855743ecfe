"""
The one YAML loader: same results as yaml.safe_load for ordinary files, hostile ones refused.

Every refusal is checked with both parsers (libyaml's and PyYAML's own), since the checks run
in the composer that both share.
"""

from pathlib import Path

from hypothesis import given, HealthCheck, settings, strategies as st
import pytest
import yaml

from emfc_ros.core import safe_yaml
from emfc_ros.core.errors import ConfigError
from emfc_ros.core.safe_yaml import (load_yaml_file, load_yaml_text, MAX_ALIAS_NODES,
                                     MAX_ALIASES, MAX_DEPTH, MAX_YAML_BYTES, YamlRefused)

CONFIG = Path(__file__).resolve().parents[2] / 'config'
LOADERS = ['c', 'python'] if safe_yaml._CParser is not None else ['python']


@pytest.fixture(params=LOADERS)
def loader(request, monkeypatch):
    """Run the test with each parser under the guarded composer."""
    if request.param == 'python':
        monkeypatch.setattr(safe_yaml, '_Loader', safe_yaml._PyLoader)
    return request.param


def laughs(width, levels, scalar='lol'):
    """A billion-laughs document: each level a list of ``width`` aliases of the one before."""
    lines = [f'l0: &l0 [{", ".join([scalar] * width)}]']
    for i in range(1, levels):
        lines.append(f'l{i}: &l{i} [{", ".join([f"*l{i - 1}"] * width)}]')
    return '\n'.join(lines) + '\n'


def expanded_alias_nodes(width, levels):
    """Nodes the aliases of :func:`laughs` stand for, expanded (as the loader counts them)."""
    size = [1 + width]                                    # l0: the list and its scalars
    for _ in range(1, levels):
        size.append(1 + width * size[-1])
    return sum(width * size[i - 1] for i in range(1, levels))


def test_shipped_configs_load_as_with_safe_load(loader):
    files = sorted(CONFIG.glob('*.yaml'))
    assert len(files) >= 5
    for path in files:
        assert load_yaml_file(path) == yaml.safe_load(path.read_text()), path


def test_anchors_merge_keys_and_empty_documents_still_work(loader):
    text = 'base: &b {x: 1, y: [1, 2]}\nother:\n  <<: *b\n  y: 3\nlist: [*b, *b]\n'
    assert load_yaml_text(text) == yaml.safe_load(text)
    assert load_yaml_text('') is None
    assert load_yaml_text(b'a: 1\n') == {'a': 1}


@pytest.mark.parametrize('text, problem', [
    (laughs(9, 9), 'alias bomb'),
    (laughs(2, 40), 'alias bomb'),
    ('a: &a [1]\nb: [' + ', '.join(['*a'] * (MAX_ALIASES + 1)) + ']\n',
     f'more than {MAX_ALIASES} aliases'),
    ('a: &a [x, *a]\n', 'recursive'),
    ('a: &a {b: *a}\n', 'recursive'),
    ('[' * 100000, f'nested more than {MAX_DEPTH}'),
    ('{a: ' * 100000, f'nested more than {MAX_DEPTH}'),
    (''.join(' ' * i + 'k:\n' for i in range(MAX_DEPTH + 2)), f'nested more than {MAX_DEPTH}'),
    ('- ' * (MAX_DEPTH + 1) + 'x\n', f'nested more than {MAX_DEPTH}'),
])
def test_hostile_text_is_refused_naming_the_source(loader, text, problem):
    with pytest.raises(YamlRefused, match=problem) as info:
        load_yaml_text(text, 'plans/evil.yaml')
    assert str(info.value).startswith('plans/evil.yaml: ')
    assert info.value.key == 'plans/evil.yaml'
    assert isinstance(info.value, ConfigError) and isinstance(info.value, ValueError)


def test_limits_are_inclusive(loader):
    aliases = 'a: &a [1]\nb: [' + ', '.join(['*a'] * MAX_ALIASES) + ']\n'
    assert len(load_yaml_text(aliases)['b']) == MAX_ALIASES
    deep = '[' * MAX_DEPTH + ']' * MAX_DEPTH
    doc = load_yaml_text(deep)
    for _ in range(MAX_DEPTH - 1):
        doc = doc[0]
    assert doc == []
    with pytest.raises(YamlRefused):
        load_yaml_text('[' * (MAX_DEPTH + 1) + ']' * (MAX_DEPTH + 1))
    # an alias-of-alias document just inside the bound loads, one more level is refused
    width, levels = 10, 4
    assert expanded_alias_nodes(width, levels) <= MAX_ALIAS_NODES
    assert load_yaml_text(laughs(width, levels)) == yaml.safe_load(laughs(width, levels))
    assert expanded_alias_nodes(width, levels + 1) > MAX_ALIAS_NODES
    with pytest.raises(YamlRefused, match='alias bomb'):
        load_yaml_text(laughs(width, levels + 1))


def test_non_utf8_file_names_the_byte_offset(tmp_path, loader):
    path = tmp_path / 'plan.yaml'
    path.write_bytes(b'run:\n  name: caf\xe9\n')
    with pytest.raises(YamlRefused) as info:
        load_yaml_file(path)
    assert str(info.value) == (f'{path}: YAML refused: not UTF-8 text (byte 0xe9 at offset '
                               '16 B)')


def test_file_over_the_size_cap_is_refused_unread(tmp_path):
    path = tmp_path / 'big.yaml'
    path.write_bytes(b'#' * (MAX_YAML_BYTES + 1))
    with pytest.raises(YamlRefused, match=f'larger than {MAX_YAML_BYTES} B'):
        load_yaml_file(path)
    path.write_bytes(b'#' * (MAX_YAML_BYTES - 2) + b'\n')
    assert load_yaml_file(path) is None
    with pytest.raises(YamlRefused, match='larger than'):
        load_yaml_text('#' * (MAX_YAML_BYTES + 1))


def test_syntax_errors_stay_yaml_errors_naming_the_file(tmp_path, loader):
    path = tmp_path / 'bad.yaml'
    path.write_text('a: [unclosed\n')
    with pytest.raises(yaml.YAMLError, match='bad.yaml'):
        load_yaml_file(path)
    with pytest.raises(OSError):
        load_yaml_file(tmp_path / 'missing.yaml')


# -- property-based ---------------------------------------------------------------------------

# No '*' in the strings: the alias count below counts '*id' in the dumped text. No NEL:
# PyYAML's own dump and safe_load do not round-trip it (both loaders read it as a space).
text = st.text(alphabet=st.characters(blacklist_characters='*\x85',
                                      blacklist_categories=('Cs',)),
               max_size=8)
scalars = st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6),
                    st.floats(allow_nan=False, width=32), text)
documents = st.recursive(
    scalars, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                     st.dictionaries(text, inner, max_size=4)),
    max_leaves=30)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(documents, st.sampled_from(['block', 'flow']))
def test_random_documents_load_as_with_safe_load(doc, style):
    text = yaml.safe_dump(doc, default_flow_style=style == 'flow', allow_unicode=True)
    assert load_yaml_text(text) == yaml.safe_load(text) == doc
    assert load_yaml_text(text.encode('utf-8')) == doc


@settings(max_examples=100, deadline=None)
@given(st.lists(documents, min_size=1, max_size=4),
       st.lists(st.integers(0, 3), min_size=1, max_size=120))
def test_random_shared_nodes_load_or_are_refused_for_their_alias_count(pool, picks):
    # safe_dump writes a list or mapping that appears twice as an anchor and aliases.
    doc = {'items': [pool[i % len(pool)] for i in picks]}
    text = yaml.safe_dump(doc)
    aliases = text.count('*id')
    try:
        got = load_yaml_text(text)
    except YamlRefused as exc:
        assert aliases > MAX_ALIASES and f'more than {MAX_ALIASES} aliases' in str(exc)
    else:
        assert aliases <= MAX_ALIASES and got == doc


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 12), st.integers(1, 12))
def test_random_alias_bombs_are_refused_exactly_when_they_expand_too_far(width, levels):
    text = laughs(width, levels)
    aliases = width * (levels - 1)
    try:
        got = load_yaml_text(text)
    except YamlRefused:
        assert aliases > MAX_ALIASES or expanded_alias_nodes(width, levels) > MAX_ALIAS_NODES
    else:
        assert aliases <= MAX_ALIASES and expanded_alias_nodes(width, levels) <= MAX_ALIAS_NODES
        assert got == yaml.safe_load(text)


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=200))
def test_random_bytes_give_a_document_or_a_yaml_error(data):
    try:
        data.decode('utf-8')
    except UnicodeDecodeError as exc:
        with pytest.raises(YamlRefused, match=f'at offset {exc.start} B'):
            load_yaml_text(data, 'x.yaml')
        return
    try:
        load_yaml_text(data, 'x.yaml')
    except (YamlRefused, yaml.YAMLError):
        pass


@settings(max_examples=60, deadline=None)
@given(st.integers(MAX_DEPTH + 1, 3000), st.sampled_from(['[', '{a: ', '- ']))
def test_random_deep_nesting_is_refused(depth, opener):
    text = opener * depth + ('x' if opener == '- ' else '')
    with pytest.raises(YamlRefused, match='nested'):
        load_yaml_text(text, 'deep.yaml')
