"""
The DAQ/FPGA bridge's core: device back-ends, the UDP protocol and the device emulator.

No ROS imports. The back-ends are registered by name in :mod:`~.registry`
(:data:`BACKENDS`, :func:`backend_from_mapping`); every back-end follows
:class:`DeviceBackend`. The protocol is specified in ``docs/device_protocol.md``.
"""

from emfc_ros.core.device.backend import (default_device_config, device_config_from_mapping,
                                          DeviceBackend, DeviceConfig, InputChannel,
                                          OutputChannel)
from emfc_ros.core.device.emulator import DeviceEmulator, Faults
from emfc_ros.core.device.errors import (DeviceConfigError, DeviceError, DeviceRefusedError,
                                         DeviceTimeoutError, ProtocolError)
from emfc_ros.core.device.function_generator import FunctionGenerator, GeneratorSpec
from emfc_ros.core.device.registry import backend_from_mapping, BACKENDS, create_backend
from emfc_ros.core.device.sim_backend import SimBackend, SimulatedDevice
from emfc_ros.core.device.udp_backend import ReorderBuffer, UdpBackend

__all__ = [
    'BACKENDS', 'DeviceBackend', 'DeviceConfig', 'DeviceConfigError', 'DeviceEmulator',
    'DeviceError', 'DeviceRefusedError', 'DeviceTimeoutError', 'Faults', 'FunctionGenerator',
    'GeneratorSpec', 'InputChannel', 'OutputChannel', 'ProtocolError', 'ReorderBuffer',
    'SimBackend', 'SimulatedDevice', 'UdpBackend', 'backend_from_mapping', 'create_backend',
    'default_device_config', 'device_config_from_mapping',
]
