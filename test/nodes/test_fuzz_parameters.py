"""
Property-based fuzzing of the parameter validators: start-up values and run-time sets.

Whatever names and values (any type, NaN, infinities, huge numbers, lists, unknown names)
a user passes, :func:`~emfc_ros.nodes.params.declare_table` never raises; a value is either
taken (of the default's type, finite and within its limits) or refused with a message
naming the parameter, the default kept. The daq_bridge built from such values never raises
and is in state ``error`` whenever one was refused; at run time a set either succeeds with a
valid value or is refused with a reason, never an exception.
"""

import math

from hypothesis import given, HealthCheck, settings, strategies as st
import rclpy
from rclpy.parameter import Parameter

from emfc_ros.core.device.backend import check_generator_range
from emfc_ros.core.device.function_generator import GeneratorSpec
from emfc_ros.nodes import daq_bridge, plant_simulator, recorder, signal_generator, weighing
from emfc_ros.nodes.params import declare_table, pending_refusals, refuse_unknown

FUZZ = settings(max_examples=60, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow])
INT64 = st.integers(-2 ** 63, 2 ** 63 - 1)
FLOATS = st.floats(allow_nan=True, allow_infinity=True)
SCALARS = st.one_of(st.booleans(), INT64, FLOATS, st.sampled_from([0, -1, 1e300, -1e-300]),
                    st.text(max_size=8))
VALUES = st.one_of(SCALARS, st.lists(FLOATS, min_size=1, max_size=3),
                   st.lists(INT64, min_size=1, max_size=3),
                   st.lists(st.text(max_size=5), min_size=1, max_size=3))
TABLES = {'daq_bridge': (daq_bridge.PARAMETERS, daq_bridge.LIMITS, daq_bridge.READ_ONLY),
          'plant_simulator': (plant_simulator.PARAMETERS, plant_simulator.LIMITS,
                              plant_simulator.READ_ONLY),
          'signal_generator': (signal_generator.PARAMETERS, signal_generator.LIMITS, ()),
          'recorder': (recorder.PARAMETERS, recorder.LIMITS, ()),
          'weighing': (weighing.PARAMETERS, weighing.LIMITS, ())}


def _overrides(table, data):
    names = data.draw(st.lists(st.sampled_from(sorted(table)) | st.sampled_from(
        ['no_such_parameter', 'udp.device_prot', 'sample_rate_hz']), max_size=6, unique=True))
    return {name: data.draw(VALUES) for name in names}


def _same(a, b):
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    sequences = [isinstance(x, (list, tuple)) or hasattr(x, 'tolist') for x in (a, b)]
    if any(sequences):
        return all(sequences) and len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return type(a) is type(b) and a == b


@FUZZ
@given(st.sampled_from(sorted(TABLES)), st.data())
def test_declare_table_takes_valid_values_and_refuses_the_rest_by_name(ros_context, which,
                                                                       data):
    table, limits, read_only = TABLES[which]
    overrides = _overrides(table, data)
    node = rclpy.create_node('fuzz', context=ros_context, parameter_overrides=[
        Parameter(k, value=v) for k, v in overrides.items()])
    try:
        refused = declare_table(node, table, limits, read_only)
        refused += refuse_unknown(node)
        for name in overrides:
            if name not in table:
                assert any(name in r and 'unknown' in r for r in refused), (name, refused)
        for name, entry in table.items():
            default = entry[0]
            if isinstance(default, Parameter.Type):
                continue                        # declared without a default: no value
            value = node.get_parameter(name).value
            said = [r for r in refused if r.startswith(f'parameter {name}:')]
            if name in overrides and not _same(value, overrides[name]) and not (
                    isinstance(default, float) and isinstance(overrides[name], int)
                    and not isinstance(overrides[name], bool)
                    and value == float(overrides[name])):
                assert said and _same(value, default), (name, overrides[name], value, said)
            if name in limits and not said:
                low, high = limits[name]
                assert isinstance(value, (int, float)) and not isinstance(value, bool)
                assert math.isfinite(value) and low <= value <= high, (name, value)
        assert bool(pending_refusals(node)) == bool(refused)
    finally:
        node.destroy_node()


def _bridge(context, overrides):
    params = {'backend': 'sim', 'autostart': False}
    params.update(overrides)
    return daq_bridge.DaqBridgeNode(context=context, parameter_overrides=[
        Parameter(k, value=v) for k, v in params.items()])


@settings(max_examples=25, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(st.data())
def test_the_bridge_never_raises_on_start_up_values_and_refusals_mean_error(ros_context, data):
    table = {k: v for k, v in daq_bridge.PARAMETERS.items() if k not in ('backend', 'autostart')}
    overrides = _overrides(table, data)
    node = _bridge(ros_context, overrides)
    try:
        values = node.diagnostic_values()
        if pending_refusals(node):
            assert values['state'] == 'error' and values['error'], values
        if values['state'] != 'error':
            for name, (low, high) in daq_bridge.LIMITS.items():
                value = node.get_parameter(name).value
                assert math.isfinite(value) and low <= value <= high, (name, value)
            for name in daq_bridge.RUNTIME:
                assert math.isfinite(node.session.runtime[name])
    finally:
        node.destroy_node()


RUNTIME_NAMES = list(daq_bridge.RUNTIME) + ['funcgen.coil.amplitude_V', 'funcgen.coil.offset_V',
                                            'funcgen.coil.waveform', 'funcgen.coil.gain',
                                            'funcgen.coil.frequency_Hz', 'sample_rate_Hz',
                                            'udp.key_file']


@settings(max_examples=200, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(st.data())
def test_run_time_sets_are_valid_or_refused_with_a_reason(ros_context, data):
    node = _bridge(ros_context, {'excitation_mode': 'function_generator',
                                 'funcgen.coil.waveform': 'sine',
                                 'funcgen.coil.frequency_Hz': 10.0})
    try:
        for _ in range(data.draw(st.integers(1, 5))):
            name = data.draw(st.sampled_from(RUNTIME_NAMES))
            value = data.draw(VALUES)
            try:
                param = Parameter(name, value=value)
            except (TypeError, ValueError):
                continue
            (result,) = node.set_parameters([param])
            if not result.successful:
                assert result.reason, (name, value)
                continue
            now = node.get_parameter(name).value
            if name in daq_bridge.RUNTIME:
                runtime = node.session.runtime[name]
                assert math.isfinite(runtime) and runtime >= 0.0
            elif name.startswith('funcgen.'):
                assert name != 'funcgen.coil.waveform' or now in (
                    'off', 'sine', 'chirp', 'prbs', 'constant')
                # What the bridge would send is a valid generator within the limits.
                check_generator_range(node.session.specs, node.session.config)
                assert all(isinstance(s, GeneratorSpec) for s in node.session.specs)
            else:
                raise AssertionError(f'start-up parameter {name} set at run time')
    finally:
        node.destroy_node()


def test_the_generator_amplitude_is_bounded_by_the_output_limits_not_by_100_V(ros_context):
    node = _bridge(ros_context, {'excitation_mode': 'function_generator',
                                 'funcgen.coil.waveform': 'sine',
                                 'funcgen.coil.frequency_Hz': 10.0,
                                 'output_min_V': [-2.0, -10.0], 'output_max_V': [2.0, 10.0]})
    try:
        assert node.set_parameters([Parameter('funcgen.coil.amplitude_V',
                                              value=1.5)])[0].successful
        (result,) = node.set_parameters([Parameter('funcgen.coil.amplitude_V', value=5.0)])
        assert not result.successful and 'beyond the output limits [-2, 2] V' in result.reason
        (result,) = node.set_parameters([Parameter('funcgen.coil.offset_V', value=1.0)])
        assert not result.successful and 'coil_V' in result.reason      # 1 + 1.5 > 2
    finally:
        node.destroy_node()
    # At start-up the same bound: the node says why and stays in state error.
    node = _bridge(ros_context, {'excitation_mode': 'function_generator',
                                 'funcgen.coil.waveform': 'constant',
                                 'funcgen.coil.offset_V': 12.0})
    try:
        values = node.diagnostic_values()
        assert values['state'] == 'error' and 'beyond the output limits' in values['error']
    finally:
        node.destroy_node()
