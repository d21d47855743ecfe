"""The message accounting per stream (no silent loss): sums, problems, YAML round trip."""

import pytest
import yaml

from emfc_ros.core.run_plan import (
    PLANT_STATE_WALL_RATE_HZ, runner_state_wall_rate_Hz, SimulatorPlan)
from emfc_ros.core.stream_counts import (
    from_mapping, markdown, problems, states_due, StreamCount, to_yaml)


def test_states_due_counts_the_samples_of_each_block_on_the_state_grid():
    # 10 kHz, 10 Hz: sample 0 of every 1000-sample block
    assert states_due([1000] * 490, 10000.0, 10.0) == 490
    # 1 kHz states: samples 0, 10, ..., 990 of each block; a short last block of 15
    # samples still has its samples 0 and 10
    assert states_due([1000, 1000, 15], 10000.0, 1000.0) == 100 + 100 + 2
    assert states_due([1000], 10000.0, 0.0) == 0
    # a state rate above the sample rate: every sample
    assert states_due([7, 3], 100.0, 1000.0) == 10
    # the grid is the sample index's, not each block's: samples 0, 10, ..., 830 of 833
    assert states_due([128] * 6 + [65], 10000.0, 1000.0) == 84


def test_counts_that_add_up_are_no_problem_and_the_table_says_so():
    counts = [StreamCount('/emfc/joint_states', 484, 484, 0, 6, 490),
              StreamCount('/emfc/excitation', 492, 492, 2, 0, 490),
              StreamCount('/diagnostics', 9)]
    assert problems(counts) == []
    text = '\n'.join(markdown(counts))
    assert '| `/emfc/joint_states` | 490 | 484 | 0 | 6 | 484 | 0 |' in text
    assert '| `/diagnostics` | - | - | 0 | 0 | 9 | - |' in text
    assert 'Every message published on the 2 counted streams is in the bag' in text
    assert '6 messages were left out by the wall-rate limit' in text


def test_lost_and_unaccounted_messages_are_named():
    lost = StreamCount('/emfc/joint_states', 1488, 49000, 0, 0, 49000)
    short = StreamCount('/clock', 489, 489, 0, 0, 490)
    extra = StreamCount('/emfc/measurements', 491, 490, 0, 0, 490)
    found = problems([lost, short, extra])
    assert found == [
        '/emfc/joint_states: 47512 lost (49000 published, 1488 recorded)',
        '/clock: 489 published - 0 repeated + 0 decimated != 490 due',
        '/emfc/measurements: 1 more recorded than published (490 published, 491 recorded)']
    assert lost.lost == 47512
    assert '**Messages lost or unaccounted for:**' in '\n'.join(markdown([lost]))


def test_the_custom_data_text_reads_back():
    counts = [StreamCount('/emfc/joint_states', 484, 484, 0, 6, 490),
              StreamCount('/emfc/excitation', 492, 492, 2, 0, 490),
              StreamCount('/diagnostics', 9)]
    doc = yaml.safe_load(to_yaml(counts))
    assert doc['/emfc/joint_states'] == {'due': 490, 'published': 484, 'repeated': 0,
                                         'decimated': 6, 'recorded': 484, 'lost': 0}
    assert from_mapping(doc) == counts
    with pytest.raises(ValueError, match='recorded'):
        from_mapping({'/a': {'published': 3}})
    with pytest.raises(ValueError, match='published must be an integer'):
        from_mapping({'/a': {'recorded': 3, 'published': 'many'}})


def test_the_runner_limits_states_only_above_one_per_block_on_the_wait_set_executor():
    default = SimulatorPlan()                               # 10 Hz states
    wait_set = 'single_threaded'
    assert runner_state_wall_rate_Hz(default, 10000.0, 1000, wait_set) == 0.0
    assert runner_state_wall_rate_Hz(SimulatorPlan(state_rate_Hz=100.0), 10000.0, 100,
                                     wait_set) == 0.0
    fast = SimulatorPlan(state_rate_Hz=1000.0)
    assert runner_state_wall_rate_Hz(fast, 10000.0, 1000, wait_set) == PLANT_STATE_WALL_RATE_HZ
    given = SimulatorPlan(state_rate_Hz=1000.0, max_state_wall_rate_Hz=250.0)
    assert runner_state_wall_rate_Hz(given, 10000.0, 1000, wait_set) == 250.0


def test_the_events_executor_needs_no_limit_up_to_the_history_depth_per_block():
    fast = SimulatorPlan(state_rate_Hz=1000.0)             # 100 states per 1000-sample block
    assert runner_state_wall_rate_Hz(fast, 10000.0, 1000) == 0.0
    every = SimulatorPlan(state_rate_Hz=10000.0)           # one per sample
    assert runner_state_wall_rate_Hz(every, 10000.0, 1000, 'events') == 0.0
    assert runner_state_wall_rate_Hz(every, 10000.0, 1001, 'events') == \
        PLANT_STATE_WALL_RATE_HZ
    given = SimulatorPlan(state_rate_Hz=1000.0, max_state_wall_rate_Hz=250.0)
    assert runner_state_wall_rate_Hz(given, 10000.0, 1000, 'events') == 250.0
