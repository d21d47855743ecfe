"""
The NI-DAQmx error codes this project acts on, with NI's texts.

The codes are NI-DAQmx's (``nidaqmx.error_codes.DAQmxErrors``; this module does not import
``nidaqmx``, an optional extra). The ``daqmx`` back-end turns each code that means lost or
unapplied samples into a latched fault (:data:`FAULT_OF_CODE`); the emulated device answers
with the same codes and texts.
"""

from __future__ import annotations

from typing import Dict

#: AO: the host did not write samples in time; the device stopped rather than regenerate.
GEN_STOPPED_TO_PREVENT_REGEN_OF_OLD_SAMPLES = -200290
#: AO: the driver could not move samples to the device fast enough.
OUTPUT_FIFO_UNDERFLOW_2 = -200621
#: AI: the host did not read in time; the buffer's oldest samples were overwritten.
SAMPLES_NO_LONGER_AVAILABLE = -200279
#: AI: the read timed out before the requested samples were acquired.
SAMPLES_NOT_YET_AVAILABLE = -200284
#: The device is gone (surprise removal, power loss, cable).
DEVICE_REMOVED = -200045
#: The device cannot be accessed.
DEV_CANNOT_BE_ACCESSED = -201003
#: A write after the watchdog timer expired (outputs at their expiration states).
WRITE_FAILED_BECAUSE_WATCHDOG_EXPIRED = -200678
#: The task handle is unknown.
INVALID_TASK = -200088
#: A physical channel name that the device does not have.
INVALID_PHYS_CHAN_NAME = -201237
#: The function is not supported by the device or the driver.
FUNCTION_NOT_SUPPORTED_FOR_DEVICE = -209876
#: The device has no watchdog timer.
WATCHDOG_TIMER_NOT_SUPPORTED = -200662
#: A task of that name exists already.
DUPLICATE_TASK = -200089
#: A property's requested value is outside what the device allows.
INVALID_ATTRIBUTE_VALUE = -200077
#: Analog input and analog output channels in one task.
MULTI_CHAN_TYPES_IN_TASK = -200559
#: A terminal that cannot be the source of this clock or trigger.
INVALID_ROUTING_SOURCE_TERMINAL_NAME = -200040
#: The resource (the AI timing engine) is used by another task.
RESOURCE_ALREADY_RESERVED = -200022
#: A property the device does not have.
ATTR_NOT_SUPPORTED = -200197
#: AO: the samples do not fit in the buffer (yet: it frees up as the device generates).
SAMPLES_CAN_NOT_YET_BE_WRITTEN = -200292

#: NI's texts (the first sentence or two of the driver's message).
TEXTS: Dict[int, str] = {
    GEN_STOPPED_TO_PREVENT_REGEN_OF_OLD_SAMPLES: (
        'The generation has stopped to prevent the regeneration of old samples. Your '
        'application was unable to write samples to the background buffer fast enough to '
        'prevent old samples from being regenerated.'),
    OUTPUT_FIFO_UNDERFLOW_2: (
        'Onboard device memory underflow. Because of system and/or bus-bandwidth '
        'limitations, the driver could not write data to the device fast enough to keep up '
        'with the device output rate.'),
    SAMPLES_NO_LONGER_AVAILABLE: (
        'The application is not able to keep up with the hardware acquisition. Increasing '
        'the buffer size, reading the data more frequently, or specifying a fixed number of '
        'samples to read instead of reading all available samples might correct the '
        'problem.'),
    SAMPLES_NOT_YET_AVAILABLE: (
        'Some or all of the samples requested have not yet been acquired. To wait for the '
        'samples to become available use a longer read timeout or read later in your '
        'program.'),
    DEVICE_REMOVED: 'The device has been removed from the system.',
    DEV_CANNOT_BE_ACCESSED: (
        'Device cannot be accessed. Possible causes: Device is no longer present in the '
        'system. Device is not powered. Device is powered, but was temporarily without power.'),
    WRITE_FAILED_BECAUSE_WATCHDOG_EXPIRED: (
        'Write cannot be performed, because the watchdog timer has expired. Clear the '
        'expiration of the watchdog task before writing.'),
    INVALID_TASK: 'Task specified is invalid or does not exist.',
    INVALID_PHYS_CHAN_NAME: 'Physical channel specified does not exist on this device.',
    FUNCTION_NOT_SUPPORTED_FOR_DEVICE: 'The specified function is not supported by the device.',
    WATCHDOG_TIMER_NOT_SUPPORTED: 'Watchdog timer is not supported by this device.',
    DUPLICATE_TASK: 'Task cannot be created, because a task with this name already exists.',
    INVALID_ATTRIBUTE_VALUE: 'Requested value is not a supported value for this property.',
    MULTI_CHAN_TYPES_IN_TASK: ('Task cannot contain a channel of the specified type, because '
                               'it contains channels of a different type.'),
    INVALID_ROUTING_SOURCE_TERMINAL_NAME: 'Source terminal to be routed could not be found '
                                          'on the device.',
    SAMPLES_CAN_NOT_YET_BE_WRITTEN: (
        'Some or all of the samples to write could not be written to the buffer yet. More '
        'space will free up as samples currently in the buffer are generated.'),
    ATTR_NOT_SUPPORTED: 'Specified property is not supported by the device or is not '
                        'applicable to the task.',
    RESOURCE_ALREADY_RESERVED: 'The specified resource is reserved. The operation could not '
                               'be completed as specified.',
}

#: The latched fault kind (:data:`emfc_ros.core.device.faults.KINDS`) of each code that means
#: lost or unapplied samples.
FAULT_OF_CODE: Dict[int, str] = {
    GEN_STOPPED_TO_PREVENT_REGEN_OF_OLD_SAMPLES: 'device_underrun',
    OUTPUT_FIFO_UNDERFLOW_2: 'device_underrun',
    WRITE_FAILED_BECAUSE_WATCHDOG_EXPIRED: 'device_watchdog',
    SAMPLES_NO_LONGER_AVAILABLE: 'device_lost',
    SAMPLES_NOT_YET_AVAILABLE: 'device_lost',
    DEVICE_REMOVED: 'device_lost',
    DEV_CANNOT_BE_ACCESSED: 'device_lost',
}


def text(code: int) -> str:
    """
    The driver text of an NI-DAQmx error code.

    Parameters
    ----------
    code : int
        An NI-DAQmx error code.

    Returns
    -------
    str
        The text, or a generic one naming the code.
    """
    return TEXTS.get(int(code), f'NI-DAQmx error {int(code)}.')
