"""
Fakes for ``test_bridge_session.py``: a host-paced device back-end and a recording outputs.

The back-end records every request and does what a test tells it (blocks, errors, health);
the recorder keeps everything a ``BridgeSession`` publishes; a clock is a mutable value.
"""

import collections
from typing import Any, List

import numpy as np

from emfc_ros.core.blocks import Block
from emfc_ros.core.device.errors import DeviceError
from emfc_ros.core.device.function_generator import GeneratorSpec

RATE = 10000.0
BLOCK = 100
EPOCH = 7


class FakeBackend:
    """A host-paced back-end that records every request and does what the test says."""

    name = 'fake'
    host_paced = True
    applies_excitation = True
    silence_timeout_s = 0.5
    recorded_config = None
    recorded_resolution = None
    finished = False
    intrusion_counters = ()

    def __init__(self) -> None:
        self.calls: List[str] = []
        self.setpoints: List[Any] = []                   # (first index, samples)
        self.generators: List[List[GeneratorSpec]] = []
        self.blocks: collections.deque = collections.deque()
        self.start_errors: List[Exception] = []          # raised by the next starts
        self.generator_error = self.gate = self.config = None
        self.health_values: dict = {}

    def description_extra(self):
        return {'fake_backend': True}

    def configure(self, config):
        self.calls.append('configure')
        self.config = config

    def start(self):
        self.calls.append('start')
        if self.gate is not None and not self.gate.wait(10.0):
            raise DeviceError('gate never opened')
        if self.start_errors:
            raise self.start_errors.pop(0)
        return EPOCH

    def stop(self):
        self.calls.append('stop')

    def write_setpoints(self, first_sample_index, samples_V):
        self.setpoints.append((int(first_sample_index), np.array(samples_V)))

    def set_function_generator(self, specs):
        self.calls.append('set_function_generator')
        self.generators.append(list(specs))
        if self.generator_error is not None:
            raise self.generator_error

    def script(self, first, n=BLOCK, epoch=EPOCH):
        self.blocks.append(device_block(first, n, epoch))

    def read_block(self, timeout_s=1.0):
        return self.blocks.popleft() if self.blocks else None

    def health(self):
        return dict(self.health_values)

    def take_faults(self):
        found, self.reported = getattr(self, 'reported', []), []
        return found

    def close(self):
        self.calls.append('close')


def device_block(first, n=BLOCK, epoch=EPOCH, rows=6):
    return Block(first, RATE, epoch, np.zeros((rows, n)))


class Recorder:
    """``BridgeOutputs`` that keeps everything."""

    def __init__(self) -> None:
        self.blocks, self.descriptions, self.consumed, self.states, self.logs = \
            [], [], [], [], []
        self.status = self.diagnostics = self.opened = 0

    def publish_block(self, block):
        self.blocks.append(block)

    def publish_descriptions(self, descriptions):
        self.descriptions.append(descriptions)

    def publish_consumed(self, samples):
        self.consumed.append(samples)

    def publish_states(self, stamps_ns, position_m, velocity_m_per_s, effort_N):
        self.states.append(np.array(stamps_ns))

    def status_changed(self):
        self.status += 1

    def diagnostics_due(self):
        self.diagnostics += 1

    def open_excitation(self):
        self.opened += 1

    def log(self, level, message):
        self.logs.append((level, message))

    def last_extra(self):
        return self.descriptions[-1]['measurements'].extra


class Clock:
    def __init__(self, ns):
        self.ns = ns

    def __call__(self):
        return self.ns
