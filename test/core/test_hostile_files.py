"""
Hostile files given to the commands: exit code 2 and one line naming the file, no traceback.

Plans, experiment files, identification options, bridge parameters files and bag metadata
that are not UTF-8, nested 100 000 deep or alias bombs (see emfc_ros.core.safe_yaml).
Nothing here starts a node: every refusal comes from checking the plan.
"""

from pathlib import Path
import shutil

import pytest

from emfc_ros.cli import bag_info, experiment, identify
from emfc_ros.core.bag import BagFormatError, read_metadata, read_streams
from emfc_ros.core.errors import ConfigError
from emfc_ros.core.run_plan import load_plan

CONFIG = Path(__file__).resolve().parents[2] / 'config'


def bomb(indent='', name='l'):
    """Nine levels of nine aliases: 9**9 strings when walked, a few hundred bytes of YAML."""
    lines = [f'{indent}{name}0: &{name}0 [lol, lol, lol, lol, lol, lol, lol, lol, lol]']
    for i in range(1, 9):
        lines.append(f'{indent}{name}{i}: &{name}{i} [' + ', '.join([f'*{name}{i - 1}'] * 9)
                     + ']')
    return '\n'.join(lines) + '\n'


@pytest.fixture
def configs(tmp_path):
    for path in CONFIG.glob('*.yaml'):
        shutil.copy(path, tmp_path / path.name)
    return tmp_path


def run_experiment(plan, capsys, tmp_path):
    out = tmp_path / 'out'
    code = experiment.main([str(plan), '-o', str(out)])
    err = capsys.readouterr().err
    assert not out.exists()                       # refused before anything was made
    return code, err


def one_line_naming(err, path):
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert 'Traceback' not in err and str(path) in lines[0], err
    return lines[0]


def test_non_utf8_plan(configs, capsys, tmp_path):
    plan = configs / 'plan.yaml'
    plan.write_bytes((CONFIG / 'experiment_default.yaml').read_bytes().replace(
        b'name: identification', b'name: identific\xe4tion'))
    code, err = run_experiment(plan, capsys, tmp_path)
    assert code == 2
    assert 'not UTF-8 text (byte 0xe4 at offset' in one_line_naming(err, plan)


def test_deeply_nested_plan(configs, capsys, tmp_path):
    plan = configs / 'plan.yaml'
    plan.write_text('run: ' + '[' * 100_000 + '\n')
    code, err = run_experiment(plan, capsys, tmp_path)
    assert code == 2 and 'nested more than' in one_line_naming(err, plan)


def test_alias_bomb_in_run_values(configs, capsys, tmp_path):
    plan = configs / 'plan.yaml'
    text = (CONFIG / 'experiment_default.yaml').read_text()
    plan.write_text('bombs:\n' + bomb('  ') + text.replace('  seed: 0\n', '  seed: *l8\n'))
    code, err = run_experiment(plan, capsys, tmp_path)
    assert code == 2 and 'alias bomb' in one_line_naming(err, plan)


def test_alias_bomb_under_identification(configs, capsys, tmp_path):
    plan = configs / 'plan.yaml'
    text = (CONFIG / 'experiment_default.yaml').read_text()
    assert '  identification:\n' in text
    plan.write_text(text.replace('  identification:\n', '  identification:\n' + bomb('    ')))
    code, err = run_experiment(plan, capsys, tmp_path)
    assert code == 2 and 'alias bomb' in one_line_naming(err, plan)


def test_alias_bomb_in_an_experiment_file(configs, capsys, tmp_path):
    exp = configs / 'static_characteristics.yaml'
    exp.write_text(bomb() + exp.read_text())
    code, err = run_experiment(configs / 'experiment_default.yaml', capsys, tmp_path)
    assert code == 2 and 'alias bomb' in one_line_naming(err, exp)


def test_aliased_non_list_sections_name_the_key(configs, capsys, tmp_path):
    exp = configs / 'static_characteristics.yaml'
    text = exp.read_text()
    line = '      sections: [coil_amplifier_staircase, load_changer_staircase]\n'
    assert text.count(line) == 1
    exp.write_text('nested: &nested [[a, b], [c]]\n'
                   + text.replace(line, '      sections: *nested\n'))
    code, err = run_experiment(configs / 'experiment_default.yaml', capsys, tmp_path)
    line = one_line_naming(err, exp)
    assert code == 2 and 'sections: expected a list of strings' in line


def test_alias_bomb_in_a_bridge_parameters_file(configs, capsys, tmp_path):
    params = configs / 'daq_bridge_udp.yaml'
    params.write_text(bomb() + params.read_text())
    with pytest.raises(ConfigError, match='alias bomb'):
        load_plan(configs / 'experiment_bridge_emulator.yaml')
    code, err = run_experiment(configs / 'experiment_bridge_emulator.yaml', capsys, tmp_path)
    assert code == 2 and 'alias bomb' in one_line_naming(err, params)


def test_an_ordinary_plan_still_loads(configs):
    assert load_plan(configs / 'experiment_default.yaml').name == 'identification'


def small_bag(path):
    from emfc_ros.core.bag import BagWriter
    writer = BagWriter(path)
    writer.open()
    writer.add_connection('/s', 'std_msgs/msg/String')
    writer.close()
    return path


@pytest.mark.parametrize('content, problem', [
    (b'a: \xff\n', 'not UTF-8'),
    (bomb().encode(), 'alias bomb'),
    (b'[' * 100_000, 'nested more than'),
])
def test_hostile_identification_options(tmp_path, capsys, content, problem):
    bag = small_bag(tmp_path / 'bag')
    options = tmp_path / 'options.yaml'
    options.write_bytes(content)
    assert identify.main([str(bag), '--options', str(options)]) == 2
    assert problem in one_line_naming(capsys.readouterr().err, options)


@pytest.mark.parametrize('content, problem', [
    (b'rosbag2_bagfile_information:\n  version: 9\n  \xc3(: 1\n', 'not UTF-8'),
    (('rosbag2_bagfile_information:\n' + bomb('  ')).encode(), 'alias bomb'),
])
def test_hostile_bag_metadata(tmp_path, capsys, content, problem):
    bag = small_bag(tmp_path / 'bag')
    (bag / 'metadata.yaml').write_bytes(content)
    with pytest.raises(BagFormatError, match=problem):
        read_metadata(bag)
    with pytest.raises(BagFormatError, match=problem):
        read_streams(bag)
    assert bag_info.main([str(bag)]) == 2
    assert problem in one_line_naming(capsys.readouterr().err, bag / 'metadata.yaml')
    assert identify.main([str(bag)]) == 2
    assert problem in capsys.readouterr().err.splitlines()[-1]
