"""The emulated NI-DAQmx device's core, on an injected clock, against NI's semantics."""

import numpy as np
import pytest

from emfc_ros.core.device import daqmx_errors as codes
from emfc_ros.core.device.daqmx_emulator.model import DaqmxError, Device, expand
from emfc_ros.core.device.daqmx_wiring import resolution_V

RATE = 1000.0


class Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


class Loopback:
    """ao0 -> ai3, ao1 -> ai4 (the wiring's loopbacks), ai0 = 2 * ao0."""

    def __init__(self):
        self.rates = []

    def start(self, sample_rate_Hz):
        self.rates.append(sample_rate_Hz)

    def step(self, ao_V):
        return {'ai3': ao_V[0], 'ai4': ao_V[1], 'ai0': 2.0 * ao_V[0]}


def make(buffer=10000):
    clock = Clock()
    dev = Device(Loopback(), clock=clock)
    ai = dev.create_task('ai')
    dev.add_channels(ai, 'ai', 'Dev1/ai3:4, Dev1/ai0', '', -10.0, 10.0)
    dev.timing(ai, '', RATE, buffer)
    ao = dev.create_task('ao')
    dev.add_channels(ao, 'ao', 'Dev1/ao0:1', 'coil, lc', -10.0, 10.0)
    dev.timing(ao, '/Dev1/ai/SampleClock', RATE, buffer)
    ao.regeneration = False
    return dev, clock, ai, ao


def test_sample_k_of_the_output_is_measured_at_tick_k():
    dev, clock, ai, ao = make()
    ramp = np.vstack([np.linspace(-1, 1, 500), np.linspace(2, 3, 500)])
    dev.write(ao, ramp)
    dev.start(ao)               # armed: the AI clock is not running yet
    dev.start(ai)
    assert dev.plant.rates == [RATE]
    clock.t += 0.3              # 300 ticks
    got = dev.read(ai, 300)
    step = resolution_V(10.0)
    np.testing.assert_allclose(got[0], ramp[0, :300], atol=step / 2 + 1e-12)
    np.testing.assert_allclose(got[1], ramp[1, :300], atol=step / 2 + 1e-12)
    np.testing.assert_allclose(got[2], 2 * ramp[0, :300], atol=step / 2 + 1e-12)
    # quantised to the 16-bit step of the +-10 V range
    np.testing.assert_allclose(np.round(got / step) * step, got, atol=1e-12)


def test_writing_too_late_stops_the_generation_and_holds_the_last_value():
    dev, clock, ai, ao = make()
    dev.write(ao, np.ones((2, 100)) * 0.5)
    dev.start(ao)
    dev.start(ai)
    clock.t += 0.25             # 250 ticks, 100 written
    with pytest.raises(DaqmxError) as err:
        dev.write(ao, np.zeros((2, 100)))
    assert err.value.code == codes.GEN_STOPPED_TO_PREVENT_REGEN_OF_OLD_SAMPLES
    assert ao.underflow_at == 100
    assert 'regeneration of old samples' in str(err.value)
    got = dev.read(ai, 250)
    assert np.all(np.abs(got[0] - 0.5) < resolution_V(10.0))   # held, not repeated or zeroed


def test_reading_too_late_overflows_and_too_early_times_out():
    dev, clock, ai, ao = make(buffer=200)
    ao.regeneration = True
    dev.write(ao, np.zeros((2, 10)))
    dev.start(ao)
    dev.start(ai)
    clock.t += 0.1
    with pytest.raises(DaqmxError) as err:
        dev.read(ai, 101)
    assert err.value.code == codes.SAMPLES_NOT_YET_AVAILABLE
    assert dev.read(ai, 100).shape == (3, 100)
    clock.t += 0.25             # 250 unread > 200 buffered
    with pytest.raises(DaqmxError) as err:
        dev.read(ai, 10)
    assert err.value.code == codes.SAMPLES_NO_LONGER_AVAILABLE


def test_regeneration_repeats_what_was_written():
    dev, clock, ai, ao = make()
    ao.regeneration = True
    wave = np.vstack([np.arange(10) * 0.1, np.zeros(10)])
    dev.write(ao, wave)
    dev.start(ao)
    dev.start(ai)
    clock.t += 0.035
    got = dev.read(ai, 35)
    np.testing.assert_allclose(got[0], np.tile(wave[0], 4)[:35], atol=resolution_V(10.0))


def test_a_start_triggered_output_on_its_own_clock_starts_with_the_input():
    dev, clock, ai, _ = make()
    dev.clear('ao')
    ao = dev.create_task('ao2')
    dev.add_channels(ao, 'ao', 'Dev1/ao0', '', -5.0, 5.0)
    dev.timing(ao, '', RATE, 1000)
    dev.start_trigger_on(ao, '/Dev1/ai/StartTrigger')
    ao.regeneration = False
    dev.write(ao, np.linspace(0, 1, 200)[None, :])
    dev.start(ao)
    clock.t += 0.05             # armed: nothing output before the AI task starts
    assert ao.produced == 0
    dev.start(ai)
    clock.t += 0.1
    got = dev.read(ai, 100)
    # the trigger starts both at once on clocks of one timebase: sample k is the same tick
    np.testing.assert_allclose(got[0], np.linspace(0, 1, 200)[:100], atol=resolution_V(10.0))


def test_an_unfed_watchdog_drives_the_outputs_to_their_expiration_states():
    dev, clock, ai, ao = make()
    ao.regeneration = True
    dev.write(ao, np.full((2, 10), 3.0))
    dog = dev.create_watchdog('wd', 0.1, {'ao0': 0.0, 'ao1': -1.0})
    dev.start(dev.task('wd'))
    dev.start(ao)
    dev.start(ai)
    clock.t += 0.05
    dev.feed_watchdog()         # fed at 50 ms: expires at 150 ms
    clock.t += 0.2
    got = dev.read(ai, 250)
    assert dog.expired
    assert np.all(np.abs(got[0, :149] - 3.0) < resolution_V(10.0))
    assert np.all(np.abs(got[0, 151:]) < resolution_V(10.0))
    assert np.all(np.abs(got[1, 151:] + 1.0) < resolution_V(10.0))
    with pytest.raises(DaqmxError) as err:
        dev.write(ao, np.zeros((2, 10)))
    assert err.value.code == codes.WRITE_FAILED_BECAUSE_WATCHDOG_EXPIRED


def test_a_removed_device_fails_every_call():
    dev, clock, ai, ao = make()
    dev.start(ai)
    dev.remove()
    for call in (lambda: dev.read(ai, 1), lambda: dev.write(ao, np.zeros((2, 1))),
                 lambda: dev.create_task('x')):
        with pytest.raises(DaqmxError) as err:
            call()
        assert err.value.code == codes.DEVICE_REMOVED


def test_configuration_errors_are_ni_s():
    dev, clock, ai, ao = make()
    cases = [
        (lambda: dev.create_task('ai'), codes.DUPLICATE_TASK),
        (lambda: dev.add_channels(ai, 'ai', 'Dev1/ai9', '', -1, 1), codes.INVALID_PHYS_CHAN_NAME),
        (lambda: dev.add_channels(ai, 'ai', 'Dev2/ai0', '', -1, 1), codes.INVALID_PHYS_CHAN_NAME),
        (lambda: dev.add_channels(ai, 'ao', 'Dev1/ao0', '', -1, 1),
         codes.MULTI_CHAN_TYPES_IN_TASK),
        (lambda: dev.add_channels(ai, 'ai', 'Dev1/ai1', '', -20, 1),
         codes.INVALID_ATTRIBUTE_VALUE),
        (lambda: dev.timing(ai, '', 5e6, 100), codes.INVALID_ATTRIBUTE_VALUE),
        (lambda: dev.timing(ao, '/Dev1/PFI0', RATE, 100),
         codes.INVALID_ROUTING_SOURCE_TERMINAL_NAME),
        (lambda: dev.task('nope'), codes.INVALID_TASK),
    ]
    for call, code in cases:
        with pytest.raises(DaqmxError) as err:
            call()
        assert err.value.code == code, call


def test_physical_channel_lists_expand_as_ni_writes_them():
    assert list(expand('Dev1/ai0:2, Dev1/ai5', 'Dev1')) == ['ai0', 'ai1', 'ai2', 'ai5']
    assert list(expand('/Dev1/ao1:0', 'Dev1')) == ['ao1', 'ao0']
    with pytest.raises(DaqmxError):
        expand('Dev2/ai0', 'Dev1')


def test_the_output_buffer_holds_what_is_written_and_not_yet_generated():
    dev, clock, ai, ao = make(buffer=100)
    assert dev.space_available(ao) == 100
    dev.write(ao, np.ones((2, 100)))
    assert dev.space_available(ao) == 0
    with pytest.raises(DaqmxError) as err:          # does not fit: nothing written
        dev.write(ao, np.ones((2, 1)))
    assert err.value.code == codes.SAMPLES_CAN_NOT_YET_BE_WRITTEN
    assert dev.space_available(ao) == 0
    dev.start(ao)
    dev.start(ai)
    clock.t += 0.03                                 # 30 ticks generated
    assert dev.space_available(ao) == 30
    first = dev.read(ai, 30)
    dev.write(ao, np.full((2, 30), 2.0))
    clock.t += 0.1                                  # the last of them generated
    got = np.hstack([first, dev.read(ai, 100)])
    np.testing.assert_allclose(got[0, :100], 1.0, atol=resolution_V(10.0))
    np.testing.assert_allclose(got[0, 100:], 2.0, atol=resolution_V(10.0))
