"""
Error classes of the device bridge, one per concern.

Each subclasses :class:`~emfc_ros.core.errors.EmfcError` and the matching builtin so callers
may catch either.
"""

from emfc_ros.core.errors import EmfcError


class ProtocolError(EmfcError, ValueError):
    """Bytes are not a valid frame or control message of the device protocol."""


class DeviceConfigError(EmfcError, ValueError):
    """A device configuration (channels, scaling, limits, generator) is invalid."""


class DeviceError(EmfcError, OSError):
    """The device failed, refused a request or is not in the state the call needs."""


class DeviceTimeoutError(DeviceError, TimeoutError):
    """The device did not answer a request within its timeout and retries."""


class DeviceRefusedError(DeviceError):
    """
    The device answered a request with an error status.

    Parameters
    ----------
    status : int
        The protocol status code.
    message : str
        What the device said.

    Attributes
    ----------
    status : int
        The protocol status code (see :mod:`emfc_ros.core.device.protocol`).
    """

    def __init__(self, status: int, message: str) -> None:
        self.status = status
        super().__init__(f'device refused the request (status {status}): {message}')


class AuthenticationError(ProtocolError):
    """
    A datagram's authentication does not match the receiver's key.

    Missing tag while a key is configured, a tag without a key, or a wrong tag. The header
    fields (when the header was intact) are kept so that a device can answer the request.

    Parameters
    ----------
    message : str
        What does not match.
    header : tuple or None
        The header fields after magic and version, or None when the header is not intact.

    Attributes
    ----------
    header : tuple or None
        The header fields after magic and version, or None.
    """

    def __init__(self, message: str, header: tuple = None) -> None:
        super().__init__(message)
        self.header = header
