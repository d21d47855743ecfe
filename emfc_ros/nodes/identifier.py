"""
The identifier node: identify the balance from a bag, or from live data on request.

Topics (relative to the node namespace): ``measurements`` and ``measurements/description``
(in, accumulated between ``~/start_accumulating`` and ``~/identify``),
``excitation/description`` (in, latched: the experiment's section table), ``~/progress``
(``std_msgs/String``, out: JSON with step, fraction, message), ``~/result``
(``std_msgs/String``, out, latched: JSON with ``ok`` (false when the identification failed
or could not run), the output folder, ``failures``, ``warnings`` or ``error``),
``/diagnostics`` (WARN with the failure while the last identification failed).

Services (``std_srvs/Trigger``): ``~/identify_bag`` (the bag named by the ``bag``
parameter), ``~/start_accumulating`` (buffer live measurement blocks from now on; start it
before the experiment), ``~/identify`` (identify what was accumulated). Identification runs
in a worker thread; a request while one runs is refused with the reason.

What was on the pan is never guessed. For a bag it comes from the bag (as ``emfc-identify``);
for live data from, in order, the options file (``load_mass_kg``, ``load_changer_coupled``),
the parameters ``pan.load_mass_kg``/``pan.load_changer_coupled``, or the measurement
description's ``extra`` (the plant simulator publishes both there, a daq_bridge when told
``pan.*``). Without them ``~/identify`` is refused and ``~/result`` says which parameter to set
(:mod:`emfc_ros.core.ident.live`).

Live data are cut to the experiment on the excitation's clock (a daq_bridge measures on the
device's clock from the offset its description publishes) and refused, like a bag, when a
measurement description received while accumulating reported a device fault inside the
experiment, also one a later description no longer shows (``~/reset``).
"""

from __future__ import annotations

import json
from pathlib import Path
import threading
import time
from typing import List, Optional

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import Trigger
import yaml

from emfc_ros.core.blocks import Continuity, SequenceTracker
from emfc_ros.core.errors import BlockError
from emfc_ros.core.pan_load import declared_pan_load
from emfc_ros.core.safe_yaml import load_yaml_file, one_line, YamlRefused
from emfc_ros.nodes.convert import (
    BLOCK_QOS, LATCHED_QOS, msg_to_block, msg_to_description, node_diagnostics, steady_clock)
from emfc_ros.nodes.params import (declare_table, pending_refusals, refuse_choice,
                                   refuse_unknown)
from emfc_ros.nodes.spin import node_main

PARAMETERS = {
    'bag': ('', 'bag folder for ~/identify_bag [path]'),
    'output_dir': ('identification', 'folder under which each identification writes its '
                                     'own results folder [path]'),
    'options_file': ('', 'identification options YAML (a mapping) [path]; empty: defaults'),
    'max_accumulated_samples': (50_000_000, 'bound on live accumulation [samples]'),
    'pan.load_mass_kg': (-1.0, 'live data: mass on the pan during the experiment [kg], 0 to '
                               '100; negative: not declared (then from the options file or '
                               "the measurement description's extra, else the "
                               'identification is refused)'),
    'pan.load_changer_coupled': ('', "live data: 'true' or 'false', whether the load "
                                     "changer's moving mass rode on the pan; '': not "
                                     'declared (as pan.load_mass_kg)'),
}
#: Inclusive limits of the numeric parameters (descriptors; ``ros2 param describe``).
LIMITS = {'max_accumulated_samples': (1, 2 ** 62), 'pan.load_mass_kg': (-1.0, 100.0)}
#: Shown in the start-up log line (with every parameter set to a non-default value).
STARTUP_KEYS = ('output_dir', 'bag', 'options_file')


class IdentifierNode(Node):
    """
    Run the identification pipeline on request and publish where the results are.

    Parameters
    ----------
    **kwargs
        Passed to :class:`rclpy.node.Node`.
    """

    def __init__(self, **kwargs) -> None:
        super().__init__('identifier', **kwargs)
        refused = declare_table(self, PARAMETERS, LIMITS)
        refused += refuse_choice(self, 'pan.load_changer_coupled', ('', 'true', 'false'))
        refused += refuse_unknown(self)
        self._lock = threading.Lock()
        self._busy = False
        self._accumulating = False
        self._chunks: List[np.ndarray] = []
        self._first_index: Optional[int] = None
        self._tracker = SequenceTracker()
        self._names: tuple = ()
        self._rate = 0.0
        self._extra: dict = {}            # the measurement description's extra
        self._extras: List[dict] = []     # every extra received while accumulating (faults)
        self._excitation_epoch: Optional[int] = None
        self._source = ''                 # who published the measurement description
        self._sections: list = []
        self._malformed = 0
        self._last_error = '; '.join(refused)   # reported on /diagnostics
        self._last_result = ''
        self._runs = 0
        self._pub_progress = self.create_publisher(String, '~/progress', 10)
        self._pub_result = self.create_publisher(String, '~/result', LATCHED_QOS)
        self._pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.create_subscription(Float64MultiArray, 'measurements', self._on_block, BLOCK_QOS)
        self.create_subscription(String, 'measurements/description', self._on_description,
                                 LATCHED_QOS)
        self.create_subscription(String, 'excitation/description', self._on_experiment,
                                 LATCHED_QOS)
        self.create_service(Trigger, '~/identify_bag', self._srv_identify_bag)
        self.create_service(Trigger, '~/start_accumulating', self._srv_start)
        self.create_service(Trigger, '~/identify', self._srv_identify)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.create_timer(1.0, self._publish_diagnostics, clock=steady_clock())

    # -- parameters ------------------------------------------------------------------------

    def _on_set_parameters(self, params: List[Parameter]) -> SetParametersResult:
        for p in params:
            if p.name in ('bag', 'output_dir', 'options_file') and \
                    p.type_ != Parameter.Type.STRING:
                return SetParametersResult(successful=False, reason=f'{p.name} must be a path')
            if p.name == 'options_file' and p.value:
                try:
                    self._read_options(p.value)
                except ValueError as exc:
                    return SetParametersResult(successful=False, reason=str(exc))
            if p.name == 'max_accumulated_samples' and (
                    p.type_ != Parameter.Type.INTEGER or p.value < 1):
                return SetParametersResult(successful=False,
                                           reason='max_accumulated_samples must be >= 1')
            if p.name == 'pan.load_changer_coupled' and p.value not in ('', 'true', 'false'):
                return SetParametersResult(
                    successful=False, reason="pan.load_changer_coupled must be 'true', "
                                             f"'false' or '' (not declared), got {p.value!r}")
        return SetParametersResult(successful=True)

    @staticmethod
    def _read_options(path: str) -> dict:
        try:
            options = load_yaml_file(path) or {}
        except YamlRefused as exc:
            raise ValueError(f'options_file {exc}') from exc
        except (OSError, yaml.YAMLError) as exc:
            raise ValueError(f'options_file {path}: {one_line(exc)}') from exc
        if not isinstance(options, dict):
            raise ValueError(f'options_file {path} must hold a mapping')
        return options

    def _options(self) -> dict:
        path = self.get_parameter('options_file').value
        return self._read_options(path) if path else {}

    # -- live data -------------------------------------------------------------------------

    def _on_description(self, msg: String) -> None:
        try:
            description = msg_to_description(msg)
        except BlockError as exc:
            self._malformed += 1
            self._last_error = str(exc)
            return
        self._names = description.channel_names
        self._rate = description.sample_rate_Hz
        self._extra = dict(description.extra)
        self._source = description.source
        if self._accumulating and (not self._extras or self._extras[-1] != self._extra):
            self._extras.append(self._extra)

    def _on_experiment(self, msg: String) -> None:
        try:
            description = msg_to_description(msg)
            self._sections = list(description.extra.get('sections', []))
            self._excitation_epoch = description.epoch
        except BlockError as exc:
            self._malformed += 1
            self._last_error = str(exc)

    def _on_block(self, msg: Float64MultiArray) -> None:
        if not self._accumulating:
            return
        try:
            block = msg_to_block(msg, expected_channels=len(self._names) or None)
        except BlockError as exc:
            self._malformed += 1
            self._last_error = str(exc)
            return
        kind = self._tracker.observe(block.first_sample_index, block.n_samples, block.epoch)
        if kind not in (Continuity.FIRST, Continuity.CONTIGUOUS):
            self._last_error = f'measurement stream {kind.value} at sample ' \
                               f'{block.first_sample_index}: accumulation stopped'
            self._accumulating = False
            return
        if self._first_index is None:
            self._first_index = block.first_sample_index
        self._chunks.append(np.array(block.samples))
        accumulated = sum(c.shape[1] for c in self._chunks)
        if accumulated > int(self.get_parameter('max_accumulated_samples').value):
            self._accumulating = False
            self._last_error = 'max_accumulated_samples reached: accumulation stopped'

    # -- services --------------------------------------------------------------------------

    def _claim(self) -> Optional[str]:
        with self._lock:
            if self._busy:
                return 'an identification is running; wait for ~/result'
            self._busy = True
        return None

    def _srv_start(self, request: Trigger.Request, response: Trigger.Response):
        self._chunks, self._first_index = [], None
        self._tracker = SequenceTracker()
        self._extras = [self._extra] if self._extra else []
        self._accumulating = True
        self._last_error = ''
        response.success = True
        response.message = 'accumulating measurement blocks; call ~/identify when done'
        return response

    def _srv_identify(self, request: Trigger.Request, response: Trigger.Response):
        self._accumulating = False
        if not self._chunks:
            response.success, response.message = False, 'nothing accumulated (call ' \
                '~/start_accumulating before the experiment)'
            return response
        if not self._sections:
            response.success, response.message = False, \
                'no section table: excitation/description has not been received'
            return response
        from emfc_ros.core.ident.live import live_recording, resolve_live_plant
        samples = np.concatenate(self._chunks, axis=1)
        try:
            # on the excitation's clock (a daq_bridge measures from an offset), refused when
            # the device reported that the excitation was not applied as commanded; then
            # refused when the pan load is not known: at once, and on ~/result
            recording = live_recording(
                {name: samples[i] for i, name in enumerate(self._names)}, self._first_index,
                self._sections, self._rate, self._extras or [self._extra],
                self._excitation_epoch, self.get_namespace().rstrip('/'))
            resolve_live_plant(self._options(), self._declared(), self._extra)
        except ValueError as exc:
            self._publish_result({'ok': False, 'output': None, 'error': str(exc),
                                  'failures': [str(exc)], 'warnings': []})
            self._last_error = str(exc)
            response.success, response.message = False, str(exc)
            return response
        busy = self._claim()
        if busy:
            response.success, response.message = False, busy
            return response
        out = self._next_output('live')
        threading.Thread(target=self._work_arrays, args=(recording, out), daemon=True).start()
        n = len(next(iter(recording.values()))) if recording else 0
        response.success, response.message = True, f'identifying {n} samples into {out}'
        return response

    def _srv_identify_bag(self, request: Trigger.Request, response: Trigger.Response):
        bag = Path(self.get_parameter('bag').value)
        if not (bag / 'metadata.yaml').is_file():
            response.success, response.message = False, f'bag {bag} has no metadata.yaml ' \
                '(set the bag parameter; repair a killed recording with emfc-bag-repair)'
            return response
        busy = self._claim()
        if busy:
            response.success, response.message = False, busy
            return response
        out = self._next_output(bag.name)
        threading.Thread(target=self._work_bag, args=(bag, out), daemon=True).start()
        response.success, response.message = True, f'identifying {bag} into {out}'
        return response

    def _next_output(self, stem: str) -> Path:
        self._runs += 1
        name = f'{stem}-{time.strftime("%Y%m%d-%H%M%S")}-{self._runs}'
        return Path(self.get_parameter('output_dir').value) / name

    # -- work ------------------------------------------------------------------------------

    def _progress(self, step: str, fraction: float, message: str) -> None:
        self._pub_progress.publish(String(data=json.dumps(
            {'step': step, 'fraction': fraction, 'message': message})))

    def _work_bag(self, bag: Path, out: Path) -> None:
        from emfc_ros.core.ident.from_bag import identify_bag
        self._work(lambda options: identify_bag(bag, options, progress=self._progress)[0], out)

    def _declared(self) -> dict:
        return declared_pan_load(float(self.get_parameter('pan.load_mass_kg').value),
                                 str(self.get_parameter('pan.load_changer_coupled').value))

    def _work_arrays(self, recording: dict, out: Path) -> None:
        from emfc_ros.core.ident.live import identify_accumulated
        extra, source, declared = dict(self._extra), self._source, self._declared()
        self._work(lambda options: identify_accumulated(
            recording, self._sections, self._rate, options, extra, declared, source,
            progress=self._progress), out)

    def _work(self, run, out: Path) -> None:
        from emfc_ros.core.report import write_report
        t0 = time.monotonic()
        try:
            result = run(self._options())
            write_report(result, out)
            doc = {'ok': result.success, 'output': str(out),
                   'wall_time_s': time.monotonic() - t0, 'failures': list(result.failures),
                   'warnings': list(result.warnings)}
            if result.success:
                self._last_error = ''
                self.get_logger().info(f'identification written to {out}')
            else:
                self._last_error = 'identification failed: ' + '; '.join(result.failures)
                self.get_logger().error(f'{self._last_error} (report in {out})')
        except (ValueError, OSError, KeyError) as exc:
            doc = {'ok': False, 'output': str(out), 'error': str(exc),
                   'failures': [str(exc)], 'warnings': []}
            self._last_error = str(exc)
            self.get_logger().error(f'identification failed: {exc}')
        finally:
            with self._lock:
                self._busy = False
        self._publish_result(doc)

    def _publish_result(self, doc: dict) -> None:
        self._last_result = json.dumps(doc)
        self._pub_result.publish(String(data=self._last_result))

    def _publish_diagnostics(self) -> None:
        accumulated = sum(c.shape[1] for c in self._chunks)
        values = {'busy': self._busy, 'accumulating': self._accumulating,
                  'accumulated_samples': accumulated, 'malformed_messages': self._malformed,
                  'runs': self._runs, 'last_error': self._last_error}
        values.update(self._tracker.counters())
        level = DiagnosticStatus.WARN if self._last_error else DiagnosticStatus.OK
        message = self._last_error or 'ok'
        refused = pending_refusals(self)
        if refused:         # a refused or unknown start-up value: an error state
            level, message = DiagnosticStatus.ERROR, refused
        self._pub_diag.publish(node_diagnostics(self, 'identification', level, message,
                                                values))


main = node_main(IdentifierNode, 'identifier')


if __name__ == '__main__':
    raise SystemExit(main())
