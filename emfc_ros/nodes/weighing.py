"""
The weighing node: mass readings with uncertainty and stability from the measurement stream.

A thin node over :mod:`emfc_ros.core.weighing` (see ``docs/weighing.md``, section "ROS node").

Topics (relative to the node namespace):

- ``measurements`` (``std_msgs/Float64MultiArray``, in; parameter ``measurements_topic``):
  measurement blocks; the channels named by ``current_channel`` [A] and ``position_channel``
  [m] give the compensation force ``k(y) I`` [N].
- ``measurements/description`` (``std_msgs/String``, in, latched): names the channels.
- ``~/reading`` (``diagnostic_msgs/DiagnosticArray``, out): one stamped reading per reading
  period, released one reading period after its last sample (the look-ahead); one
  ``DiagnosticStatus`` named ``mass`` (level OK stable, WARN unstable or uncalibrated, ERROR
  no valid data) with the values ``mass_kg``, ``standard_uncertainty_kg``, ``stable``,
  ``steady``, ``calibrated``, ``unit``, ``averaging_time_s``, ``n_samples``,
  ``sample_index``, ``epoch``, ``gross_mass_kg``, ``tare_kg``, ``resolution_u_kg``,
  ``motion_u_kg``. The stamp is the time of the reading's last sample on the measurement
  sample clock: ``start_time_ns`` of the description plus ``sample_index / sample_rate_Hz``.
- ``~/dynamic`` (``diagnostic_msgs/DiagnosticArray``, out, when ``dynamic``): the dynamic
  (Kalman) estimate every ``dynamic_period_s`` of the sample clock, stamped the same way;
  one status named ``dynamic_mass`` (OK settled, WARN not) with ``mass_kg``,
  ``standard_uncertainty_kg``, ``settled``, ``calibrated``, ``unit``, ``sample_index``,
  ``epoch``, ``changes``, ``settle_threshold_kg``.
- ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray``, out, 1 Hz).

Services (``std_srvs/Trigger``, private): ``~/zero`` (empty pan), ``~/tare`` (container on
the zeroed pan), ``~/adjust`` (reference weight of ``reference_mass_kg`` on the zeroed pan),
``~/clear_tare``. Zero, tare and adjust use the latest reading's mean force and refuse when
there is no recent reading, its window is not full or it is not steady (tare and adjust
also before the first zero).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
import time
from typing import Optional

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
from rclpy.node import Node
from rclpy.qos import QoSProfile
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import Trigger

from emfc_ros.core.blocks import Continuity, SequenceTracker, StreamDescription
from emfc_ros.core.errors import BlockError
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.paths import config_file
from emfc_ros.core.weighing import DynamicWeigher, Reading, WeighingCalibration, WeighingError
from emfc_ros.core.weighing.pipeline import DynamicReading, WeighingPipeline
from emfc_ros.core.weighing.resolution import channel_resolution
from emfc_ros.nodes.convert import (BLOCK_QOS, diagnostic_status, LATCHED_QOS, msg_to_block,
                                    msg_to_description, node_diagnostics, steady_clock)
from emfc_ros.nodes.params import declare_table, refuse_unknown
from emfc_ros.nodes.spin import node_main

DEFAULT_BALANCE = 'balance_default.yaml'
#: Readings come in bursts when the stream runs faster than real time (simulation).
READING_QOS = QoSProfile(depth=100)
#: Dynamic readings (100 per simulated second by default) come in larger bursts.
DYNAMIC_QOS = QoSProfile(depth=1000)
#: Seconds between repeated log lines about bad input.
LOG_THROTTLE_S = 2.0

# name: (default, description with units, read-only)
PARAMETERS = {
    'measurements_topic': ('measurements', 'measurement block topic; its latched description '
                                           'is <topic>/description', True),
    'current_channel': ('coil_current_precise_A', 'channel with the measured coil current [A]',
                        True),
    'position_channel': ('position_m', 'channel with the measured lever-end position [m]',
                         True),
    'balance_file': ('', 'balance parameters YAML (motor coefficients, lever geometry) [path]; '
                         'empty: the shipped config/balance_default.yaml', True),
    'averaging_time_s': (1.0, 'moving-average window of a reading [s]', True),
    'reading_period_s': (0.1, 'interval between readings [s] (on the sample clock)', True),
    'stability_time_s': (0.5, 'without the dynamic estimator: readings of this last span must '
                              'agree for a stable reading [s]', True),
    'stability_threshold_kg': (1.0e-6, 'largest spread of the dynamic estimate over a '
                                       "reading's window and the next reading period for a "
                                       'stable reading [kg] (without the dynamic estimator: '
                                       'of the readings over stability_time_s)', True),
    'stale_timeout_s': (2.0, 'wall time without a valid reading after which the reading is '
                             'reported as no valid data and calibration requests are refused '
                             '[s]', True),
    'dynamic': (True, 'run the dynamic (Kalman) estimator and publish ~/dynamic', True),
    'dynamic_position_noise_m_rms': (0.0, 'dynamic estimator: position noise per sample '
                                          '[m rms]; 0: from the stream description '
                                          '(extra.resolution of the position channel: '
                                          'sqrt(noise_rms^2 + step^2 / 12))', True),
    'dynamic_force_random_walk_N_per_sqrt_s': (1.0e-6, 'dynamic estimator: random-walk '
                                                       'intensity of the pan force '
                                                       '[N/sqrt(s)]', True),
    'dynamic_period_s': (0.01, 'interval of the dynamic readings on the sample clock [s]',
                         True),
    'settle_threshold_kg': (1.0e-6, 'the dynamic estimate is settled when it will not move by '
                                    'more than this [kg]', True),
    'current_resolution_A': (0.0, 'quantisation step of the current channel [A]; 0: from the '
                                  'stream description (extra.resolution); neither: weighing '
                                  'refused', True),
    'current_noise_A_rms': (0.0, 'noise at the current converter input [A rms] with '
                                 'current_resolution_A (0: unknown, no dither assumed)', True),
    'sensitivity_kg_per_N': (0.0, 'initial sensitivity [kg/N]; 0: nominal from the lever '
                                  'geometry (negative for this balance)', True),
    'zero_force_N': (0.0, 'initial compensation force of the empty pan [N]; non-zero: a stored '
                          'zero, the balance counts as zeroed (readings can be stable before '
                          '~/zero)', True),
    'reference_mass_kg': (0.0, 'mass of the reference weight on the pan for ~/adjust [kg], '
                               '> 0; may be changed at any time', False),
    'reference_mass_u_kg': (0.0, 'standard uncertainty of the reference mass [kg], >= 0', False),
}
#: Inclusive limits of the numeric parameters (descriptors; ``ros2 param describe``);
#: reference_mass_kg 0 means not set (~/adjust refuses it).
LIMITS = {'reference_mass_kg': (0.0, 100.0), 'reference_mass_u_kg': (0.0, 100.0)}
#: Shown in the start-up log line (with every parameter set to a non-default value).
STARTUP_KEYS = ('measurements_topic', 'balance_file', 'dynamic')


def _value(x) -> str:
    """Format a value of the reading: floats at full (repr) precision, bools lower case."""
    if isinstance(x, (bool, np.bool_)):
        return 'true' if x else 'false'
    if isinstance(x, (float, np.floating)):
        return repr(float(x))
    return str(x)


def _stamp(ns: int) -> Time:
    return Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


class WeighingNode(Node):
    """
    Publish mass readings from the measurement stream; zero, tare and adjust on request.

    Parameters
    ----------
    **kwargs
        Passed to :class:`rclpy.node.Node` (for example ``parameter_overrides``).
    """

    def __init__(self, **kwargs) -> None:
        super().__init__('weighing', **kwargs)
        refused = declare_table(self, PARAMETERS, LIMITS)
        refused += refuse_unknown(self)
        self._config_error = ''   # configuration (balance, parameters): nothing works
        self._stream_error = ''   # description without what weighing needs: blocks ignored
        self._last_error = ''     # the latest problem of any kind, for the diagnostics
        self._description: Optional[StreamDescription] = None
        self._rows: Optional[tuple] = None
        self._pipeline: Optional[WeighingPipeline] = None
        self._pipeline_key = None
        self._calibration: Optional[WeighingCalibration] = None
        self._calibrated = False
        self._tracker = SequenceTracker()
        self._last_reading: Optional[Reading] = None
        self._last_reading_wall = -math.inf
        self._last_dynamic: Optional[DynamicReading] = None
        self._epoch = 0
        self._counts = {'blocks_received': 0, 'bad_blocks': 0, 'ignored_blocks': 0,
                        'dropped_blocks': 0, 'bad_descriptions': 0, 'readings': 0,
                        'dynamic_readings': 0, 'calibration_changes': 0}
        self._params = None
        self._motor = None
        try:
            self._configure_from_parameters()
        except (ValueError, OSError) as exc:
            self._config_error = f'configuration refused: {exc}'
            self._last_error = self._config_error
            self.get_logger().error(self._config_error)
        if refused:     # no readings from values nobody asked for
            self._config_error = 'configuration refused: ' + '; '.join(refused)
            self._last_error = self._config_error

        topic = str(self._param('measurements_topic'))
        self._pub_reading = self.create_publisher(DiagnosticArray, '~/reading', READING_QOS)
        self._pub_dynamic = (self.create_publisher(DiagnosticArray, '~/dynamic', DYNAMIC_QOS)
                             if self._param('dynamic') else None)
        self._pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.create_subscription(Float64MultiArray, topic, self._on_block, BLOCK_QOS)
        self.create_subscription(String, f'{topic}/description', self._on_description,
                                 LATCHED_QOS)
        self.create_service(Trigger, '~/zero', self._srv_zero)
        self.create_service(Trigger, '~/tare', self._srv_tare)
        self.create_service(Trigger, '~/adjust', self._srv_adjust)
        self.create_service(Trigger, '~/clear_tare', self._srv_clear_tare)
        self.create_timer(1.0, self._on_timer, clock=steady_clock())

    # -- configuration ---------------------------------------------------------------------

    def _param(self, name: str):
        return self.get_parameter(name).value

    def _configure_from_parameters(self) -> None:
        """Load the balance, build the initial calibration, check the filter parameters."""
        path = str(self._param('balance_file'))
        self._params = BalanceParameters.load_yaml(Path(path) if path
                                                   else config_file(DEFAULT_BALANCE))
        self._motor = tuple(self._params.motor.coeffs_N_per_A_per_mm_pow)
        for name in ('averaging_time_s', 'reading_period_s', 'stability_threshold_kg',
                     'stale_timeout_s', 'dynamic_force_random_walk_N_per_sqrt_s',
                     'dynamic_period_s', 'settle_threshold_kg'):
            value = float(self._param(name))
            if not (math.isfinite(value) and value > 0.0):
                raise WeighingError(f'{name} must be finite and > 0, got {value!r}')
        for name in ('dynamic_position_noise_m_rms', 'current_resolution_A',
                     'current_noise_A_rms'):
            value = float(self._param(name))
            if not (math.isfinite(value) and value >= 0.0):
                raise WeighingError(f'{name} must be finite and >= 0, got {value!r}')
        sensitivity = float(self._param('sensitivity_kg_per_N'))
        zero = float(self._param('zero_force_N'))
        if sensitivity == 0.0:
            self._calibration = WeighingCalibration.nominal(self._params.mechanics, zero)
        else:
            self._calibration = WeighingCalibration(sensitivity, zero)
        self._calibrated = zero != 0.0
        self._log_calibration('initial calibration' + ('' if self._calibrated else
                                                       ' (not zeroed: readings are '
                                                       'uncalibrated until ~/zero)'))
        if self._param('dynamic'):
            # Compile (or load) the estimator's kernels now, not on the first block.
            DynamicWeigher(self._params.mechanics, 10000.0).update_block(np.zeros(1),
                                                                         np.zeros(1))

    def _stream_needs(self, description: StreamDescription):
        """``(current (step, noise) [A], position noise [m])`` for a description, or a reason."""
        current_name = str(self._param('current_channel'))
        position_name = str(self._param('position_channel'))
        step = float(self._param('current_resolution_A'))
        if step > 0.0:
            current = (step, float(self._param('current_noise_A_rms')))
        else:
            current = channel_resolution(description.extra, current_name)
            if current is None:
                return (f'the resolution of {current_name!r} is unknown (the description of '
                        f'{description.stream!r} has no extra.resolution.{current_name}): '
                        'set current_resolution_A [A] (and current_noise_A_rms) so that the '
                        'uncertainty can include it')
        noise = float(self._param('dynamic_position_noise_m_rms'))
        if self._param('dynamic') and noise == 0.0:
            position = channel_resolution(description.extra, position_name)
            if position is None:
                return (f'the noise of {position_name!r} is unknown (the description of '
                        f'{description.stream!r} has no extra.resolution.{position_name}): '
                        'set dynamic_position_noise_m_rms [m], or dynamic:=false')
            noise = math.hypot(position[1], position[0] / math.sqrt(12.0))
            if noise == 0.0:
                return (f'{position_name!r} has neither noise nor quantisation: the dynamic '
                        'estimator needs dynamic_position_noise_m_rms > 0 [m]')
        return current, noise

    def _build_pipeline(self, sample_rate_Hz: float, current, position_noise: float) -> None:
        """(Re)build the weighing pipeline; the calibration is kept."""
        self._pipeline = WeighingPipeline(
            self._params.mechanics, self._motor, sample_rate_Hz, self._calibration,
            calibrated=self._calibrated,
            averaging_time_s=float(self._param('averaging_time_s')),
            reading_period_s=float(self._param('reading_period_s')),
            stability_time_s=float(self._param('stability_time_s')),
            stability_threshold_kg=float(self._param('stability_threshold_kg')),
            dynamic=bool(self._param('dynamic')),
            position_noise_m_rms=position_noise or 2.0e-9,
            force_random_walk_N_per_sqrt_s=float(
                self._param('dynamic_force_random_walk_N_per_sqrt_s')),
            dynamic_period_s=float(self._param('dynamic_period_s')),
            settle_threshold_kg=float(self._param('settle_threshold_kg')),
            current_resolution=current)
        self._last_reading = None

    # -- input -----------------------------------------------------------------------------

    def _on_description(self, msg: String) -> None:
        if self._config_error:
            return
        try:
            description = msg_to_description(msg)
        except BlockError as exc:
            self._counts['bad_descriptions'] += 1
            self._bad_input(f'malformed stream description: {exc}')
            return
        names = description.channel_names
        wanted = (str(self._param('current_channel')), str(self._param('position_channel')))
        missing = [name for name in wanted if name not in names]
        try:
            needs = self._stream_needs(description) if not missing else None
        except WeighingError as exc:
            needs = f'malformed extra.resolution in the description: {exc}'
        if missing or isinstance(needs, str):
            self._rows = None
            self._last_reading = None
            self._stream_error = needs if not missing else (
                f'the description of {description.stream!r} has no channel '
                f'{", ".join(repr(m) for m in missing)} (channels: {", ".join(names)}); set '
                'current_channel / position_channel or fix the stream')
            self._last_error = self._stream_error
            self.get_logger().error(self._stream_error)
            self._publish_error_reading(self._stream_error)
            return
        key = (description.sample_rate_Hz, needs)
        self._description = description
        self._rows = tuple(names.index(name) for name in wanted)
        if key != self._pipeline_key or self._pipeline is None:
            try:
                self._build_pipeline(description.sample_rate_Hz, *needs)
            except (ValueError, np.linalg.LinAlgError) as exc:
                self._rows = None
                self._pipeline = None
                self._stream_error = (f'cannot weigh at {description.sample_rate_Hz} Hz: '
                                      f'{exc}')
                self._last_error = self._stream_error
                self.get_logger().error(self._stream_error)
                self._publish_error_reading(self._stream_error)
                return
            self._pipeline_key = key
        if self._stream_error:
            self.get_logger().info('measurement description now complete: weighing again')
        self._stream_error = ''
        self.get_logger().info(
            f'weighing {wanted[0]!r} [A] and {wanted[1]!r} [m] of {description.stream!r} at '
            f'{description.sample_rate_Hz} Hz (epoch {description.epoch}; current resolution '
            f'{needs[0][0]:.3g} A, noise {needs[0][1]:.3g} A rms; position noise '
            f'{needs[1]:.3g} m rms)')

    def _bad_input(self, text: str) -> None:
        self._last_error = text
        self.get_logger().warning(text, throttle_duration_sec=LOG_THROTTLE_S)

    def _on_block(self, msg: Float64MultiArray) -> None:
        self._counts['blocks_received'] += 1
        if self._config_error:
            self._counts['ignored_blocks'] += 1
            return
        if self._rows is None:
            self._counts['ignored_blocks'] += 1
            self._last_reading = None
            self._bad_input(self._stream_error or 'measurement block before its description: '
                                                  'ignored')
            return
        description = self._description
        try:
            block = msg_to_block(msg, expected_channels=len(description.channels))
            if block.sample_rate_Hz != description.sample_rate_Hz:
                raise BlockError(f'block at {block.sample_rate_Hz} Hz, the description says '
                                 f'{description.sample_rate_Hz} Hz')
        except BlockError as exc:
            self._counts['bad_blocks'] += 1
            self._bad_input(f'bad measurement block: {exc}')
            return
        kind = self._tracker.observe(block.first_sample_index, block.n_samples, block.epoch)
        if kind in (Continuity.DUPLICATE, Continuity.REORDERED, Continuity.OVERLAP):
            self._counts['dropped_blocks'] += 1
            self._bad_input(f'measurement block at sample {block.first_sample_index} is '
                            f'{kind.value}: dropped')
            return
        current = block.samples[self._rows[0]]
        position = block.samples[self._rows[1]]
        if not (np.all(np.isfinite(current)) and np.all(np.isfinite(position))):
            self._counts['bad_blocks'] += 1
            self._bad_input(f'measurement block at sample {block.first_sample_index} holds '
                            'non-finite current or position: dropped (the window restarts)')
            return
        # a discontinuity (lost block, new epoch) restarts the window and the estimator; what
        # waited for the missing samples is released as not stable
        readings, dynamic = self._pipeline.push(current, position, block.first_sample_index)
        self._epoch = block.epoch
        for estimate in dynamic:
            self._publish_dynamic(estimate)
        for reading in readings:
            self._publish_reading(reading)

    # -- output ----------------------------------------------------------------------------

    def _stamp_ns(self, sample_index: int) -> int:
        description = self._description
        return int(description.start_time_ns) + int(round(
            sample_index * 1e9 / description.sample_rate_Hz))

    def _publish_reading(self, reading: Reading) -> None:
        cal = self._pipeline.calibration
        if reading.stable:
            level, message = DiagnosticStatus.OK, 'stable'
        elif not reading.calibrated:
            level, message = DiagnosticStatus.WARN, 'uncalibrated: zero the balance (~/zero)'
        else:
            level, message = DiagnosticStatus.WARN, 'unstable'
        values = {
            'mass_kg': reading.mass_kg,
            'standard_uncertainty_kg': reading.standard_uncertainty_kg,
            'stable': reading.stable,
            'steady': reading.steady,
            'calibrated': reading.calibrated,
            'unit': 'kg',
            'averaging_time_s': reading.averaging_time_s,
            'n_samples': reading.n_samples,
            'sample_index': reading.sample_index,
            'epoch': self._epoch,
            'gross_mass_kg': float(cal.gross_mass_kg(reading.mean_force_N)),
            'tare_kg': cal.tare_kg,
            'resolution_u_kg': reading.resolution_u_kg,
            'motion_u_kg': reading.motion_u_kg,
        }
        msg = DiagnosticArray()
        msg.header.stamp = _stamp(self._stamp_ns(reading.sample_index))
        msg.status = [diagnostic_status('mass', self._description.source, level, message,
                                        {k: _value(v) for k, v in values.items()})]
        self._pub_reading.publish(msg)
        self._counts['readings'] += 1
        self._last_reading = reading
        self._last_reading_wall = time.monotonic()

    def _publish_dynamic(self, estimate: DynamicReading) -> None:
        values = {
            'mass_kg': estimate.mass_kg,
            'standard_uncertainty_kg': estimate.standard_uncertainty_kg,
            'settled': estimate.settled,
            'calibrated': estimate.calibrated,
            'unit': 'kg',
            'sample_index': estimate.sample_index,
            'epoch': self._epoch,
            'changes': estimate.changes,
            'settle_threshold_kg': float(self._param('settle_threshold_kg')),
        }
        level = DiagnosticStatus.OK if estimate.settled else DiagnosticStatus.WARN
        message = 'settled' if estimate.settled else (
            'moving' if estimate.calibrated else 'uncalibrated: zero the balance (~/zero)')
        msg = DiagnosticArray()
        msg.header.stamp = _stamp(self._stamp_ns(estimate.sample_index))
        msg.status = [diagnostic_status('dynamic_mass', self._description.source, level,
                                        message, {k: _value(v) for k, v in values.items()})]
        self._pub_dynamic.publish(msg)
        self._counts['dynamic_readings'] += 1
        self._last_dynamic = estimate

    def _publish_error_reading(self, text: str) -> None:
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        nan = _value(math.nan)
        values = {'mass_kg': nan, 'standard_uncertainty_kg': nan, 'stable': 'false',
                  'unit': 'kg'}
        source = self._description.source if self._description else ''
        msg.status = [diagnostic_status('mass', source, DiagnosticStatus.ERROR, text, values)]
        self._pub_reading.publish(msg)

    def _no_data_reason(self) -> str:
        """Why there is no valid reading now ('' when there is one)."""
        if self._config_error or self._stream_error:
            return self._config_error or self._stream_error
        if self._description is None:
            return (f'waiting for {self._param("measurements_topic")}/description')
        if self._last_reading is None:
            return 'no reading yet (waiting for measurement blocks)'
        age = time.monotonic() - self._last_reading_wall
        if age > float(self._param('stale_timeout_s')):
            return (f'no reading for {age:.1f} s (is the measurement stream running?)')
        return ''

    def _on_timer(self) -> None:
        reason = self._no_data_reason()
        if reason:
            self._publish_error_reading(reason)
        self._publish_diagnostics(reason)

    def _publish_diagnostics(self, no_data: str) -> None:
        values = dict(self._counts)
        values.update({f'stream_{k}': v for k, v in self._tracker.counters().items()})
        pipeline = self._pipeline
        if pipeline is not None:
            values['window_resets'] = pipeline.gap_count
            values['samples_lost'] = pipeline.samples_lost
            values['load_changes_detected'] = pipeline.changes
        reading = self._last_reading
        if reading is not None:
            values.update({'mass_kg': _value(reading.mass_kg), 'stable': _value(reading.stable),
                           'sample_index': reading.sample_index})
        if self._last_dynamic is not None:
            values['dynamic_mass_kg'] = _value(self._last_dynamic.mass_kg)
            values['dynamic_sample_index'] = self._last_dynamic.sample_index
        cal = self._calibration
        if cal is not None:
            values.update({'sensitivity_kg_per_N': _value(cal.sensitivity_kg_per_N),
                           'zero_force_N': _value(cal.zero_force_N),
                           'tare_kg': _value(cal.tare_kg), 'calibrated': _value(self._calibrated)})
        values['channels'] = f'{self._param("current_channel")}, ' \
                             f'{self._param("position_channel")}'
        values['last_error'] = self._last_error
        if self._config_error or self._stream_error:
            level, message = DiagnosticStatus.ERROR, self._config_error or self._stream_error
        elif no_data:
            level, message = DiagnosticStatus.WARN, no_data
        elif self._last_error:
            level, message = DiagnosticStatus.WARN, f'weighing; last problem: {self._last_error}'
        elif not self._calibrated:
            level, message = DiagnosticStatus.WARN, 'weighing, not zeroed: call ~/zero'
        else:
            level, message = DiagnosticStatus.OK, 'weighing'
        self._pub_diag.publish(node_diagnostics(self, 'weighing', level, message, values))

    # -- calibration services ----------------------------------------------------------------

    def _log_calibration(self, what: str) -> str:
        cal = self._calibration
        text = (f'{what}: sensitivity {cal.sensitivity_kg_per_N!r} kg/N (u_rel '
                f'{cal.sensitivity_u_relative:.3g}), zero force {cal.zero_force_N!r} N, '
                f'tare {cal.tare_kg!r} kg')
        self.get_logger().info(text)
        return text

    def _calibrate(self, response: Trigger.Response, action: str, change):
        reason = self._no_data_reason()
        if reason:
            response.success, response.message = False, f'{action} refused: {reason}'
            return response
        try:
            reading = change(self._pipeline)
        except WeighingError as exc:
            response.success, response.message = False, str(exc)
            return response
        self._calibration = self._pipeline.calibration
        self._calibrated = self._pipeline.calibrated
        self._counts['calibration_changes'] += 1
        response.success = True
        response.message = self._log_calibration(f'{action} at sample {reading.sample_index}')
        return response

    def _srv_zero(self, request: Trigger.Request, response: Trigger.Response):
        return self._calibrate(response, 'zero', lambda p: p.zero())

    def _srv_tare(self, request: Trigger.Request, response: Trigger.Response):
        return self._calibrate(response, 'tare', lambda p: p.tare())

    def _srv_adjust(self, request: Trigger.Request, response: Trigger.Response):
        ref = self._param('reference_mass_kg')
        u_ref = self._param('reference_mass_u_kg')
        if isinstance(ref, bool) or not isinstance(ref, (int, float)) or \
                not (math.isfinite(ref) and ref > 0.0):
            response.success = False
            response.message = ('adjust refused: set the parameter reference_mass_kg to the '
                                'mass of the reference weight on the pan [kg] (> 0), got '
                                f'{ref!r}')
            return response
        return self._calibrate(response, f'adjust with {float(ref)!r} kg',
                               lambda p: p.adjust(float(ref), float(u_ref)))

    def _srv_clear_tare(self, request: Trigger.Request, response: Trigger.Response):
        if self._calibration is None:
            response.success = False
            response.message = f'clear_tare refused: {self._config_error}'
            return response
        self._calibration = dataclasses.replace(self._calibration, tare_kg=0.0, tare_u_kg=0.0)
        if self._pipeline is not None:
            self._pipeline.clear_tare()
            self._calibration = self._pipeline.calibration
        self._counts['calibration_changes'] += 1
        response.success = True
        response.message = self._log_calibration('tare cleared')
        return response

    @property
    def blocks_received(self) -> int:
        """Measurement block messages received so far (valid or not)."""
        return self._counts['blocks_received']


main = node_main(WeighingNode, 'weighing')


if __name__ == '__main__':
    raise SystemExit(main())
