"""
Message authentication of the device protocol: a pre-shared key, HMAC-SHA256 tags, replay guards.

Optional, and configured on both sides (the bridge's ``udp.key_file``, the emulator's
``--key-file``). With a key every datagram carries, before its CRC-32, a 64-bit counter and
the first :data:`TAG_BYTES` bytes of ``HMAC-SHA256(key, header + payload + counter)``
(:mod:`hmac`, :mod:`hashlib`). The header is covered, so a tag binds the session id, the
message type and the direction (request or response, measurement or setpoint stream).

Counters (:class:`Signer`) are per sender, strictly increasing and at least the sender's
wall-clock time in nanoseconds, so a sender that restarts continues above what it sent
before. Receivers keep a :class:`ReplayGuard` per session (and one for messages sent before
a session exists): a counter seen before, or older than the last :data:`REPLAY_WINDOW`
accepted ones, is a replay.

The key file (:func:`load_key_file`) holds the key as hexadecimal text (whitespace ignored),
at least :data:`MIN_KEY_BYTES` bytes; it must be readable by its owner only.
"""

from __future__ import annotations

import collections
import hashlib
import hmac
import os
from pathlib import Path
import stat
import struct
import threading
import time
from typing import Deque, Optional, Set, Union

from emfc_ros.core.device.errors import DeviceConfigError

#: Bytes of the truncated HMAC-SHA256 tag (128 bits).
TAG_BYTES = 16
#: Counter (u64) and tag, between the payload and the CRC-32.
AUTH_TRAILER = struct.Struct('<Q16s')
#: Shortest key accepted [bytes] (128 bits).
MIN_KEY_BYTES = 16
#: Longest key file read [bytes].
MAX_KEY_FILE_BYTES = 4096
#: Accepted counters a replay guard remembers (reordering tolerated within them).
REPLAY_WINDOW = 4096


class KeyFileError(DeviceConfigError):
    """A key file cannot be read or does not hold a usable key."""


def load_key_file(path: Union[str, Path]) -> bytes:
    """
    Read a pre-shared key.

    Parameters
    ----------
    path : str or Path
        A file holding the key as hexadecimal text (64 hex digits, 32 bytes, recommended;
        ``python -c "import secrets; print(secrets.token_hex(32))" > device.key`` then
        ``chmod 600 device.key``).

    Returns
    -------
    bytes
        The key.

    Raises
    ------
    KeyFileError
        If the file cannot be read, is readable by group or others, is not hexadecimal, or
        the key is shorter than :data:`MIN_KEY_BYTES` bytes.
    """
    path = Path(path)
    try:
        info = path.stat()
        if not stat.S_ISREG(info.st_mode):
            raise KeyFileError(f'key file {path}: not a regular file')
        if os.name == 'posix' and info.st_mode & 0o077:
            raise KeyFileError(f'key file {path} is accessible by group or others (mode '
                               f'{stat.S_IMODE(info.st_mode):04o}): chmod 600 {path}')
        with open(path, 'rb') as handle:
            raw = handle.read(MAX_KEY_FILE_BYTES + 1)
    except KeyFileError:
        raise
    except OSError as exc:
        raise KeyFileError(f'key file {path} cannot be read: {exc.strerror or exc}') from None
    if len(raw) > MAX_KEY_FILE_BYTES:
        raise KeyFileError(f'key file {path} is longer than {MAX_KEY_FILE_BYTES} bytes')
    try:
        text = ''.join(raw.decode('ascii').split())
        key = bytes.fromhex(text)
    except ValueError:
        raise KeyFileError(f'key file {path} must hold the key as hexadecimal text (for '
                           'example 64 hex digits)') from None
    return check_key(key, f'key file {path}')


def check_key(key: bytes, what: str = 'key') -> bytes:
    """
    Check a key's length.

    Parameters
    ----------
    key : bytes
        The key.
    what : str
        For the message.

    Returns
    -------
    bytes
        The key.

    Raises
    ------
    KeyFileError
        If shorter than :data:`MIN_KEY_BYTES` bytes.
    """
    key = bytes(key)
    if len(key) < MIN_KEY_BYTES:
        raise KeyFileError(f'{what}: the key has {len(key)} bytes, at least {MIN_KEY_BYTES} '
                           f'({2 * MIN_KEY_BYTES} hex digits) are required')
    return key


def tag(key: bytes, data: bytes) -> bytes:
    """
    The truncated HMAC-SHA256 of some bytes.

    Parameters
    ----------
    key : bytes
        The key.
    data : bytes
        Header, payload and counter.

    Returns
    -------
    bytes
        :data:`TAG_BYTES` bytes.
    """
    return hmac.digest(key, data, hashlib.sha256)[:TAG_BYTES]


class Signer:
    """
    One sender's key and counter.

    Parameters
    ----------
    key : bytes
        The pre-shared key.
    clock_ns : callable
        Wall clock [ns] (counters are at least its value).
    """

    def __init__(self, key: bytes, clock_ns=time.time_ns) -> None:
        self.key = check_key(key)
        self._clock_ns = clock_ns
        self._last = 0
        self._lock = threading.Lock()

    def next_counter(self) -> int:
        """
        The next counter: above every earlier one, at least the wall clock in ns.

        Returns
        -------
        int
            A u64.
        """
        with self._lock:
            self._last = max(self._last + 1, int(self._clock_ns()))
            return self._last

    def trailer(self, data: bytes) -> bytes:
        """
        Counter and tag for a datagram (its bytes before the trailer).

        Parameters
        ----------
        data : bytes
            Header and payload, with the authenticated flag already set.

        Returns
        -------
        bytes
            :data:`AUTH_TRAILER` bytes.
        """
        counter = self.next_counter()
        head = data + struct.pack('<Q', counter)
        return head + tag(self.key, head)


class ReplayGuard:
    """
    Accept each counter once: a counter seen before, or older than the window, is a replay.

    The window holds the last ``window`` accepted counters; a counter not above the highest
    one forgotten is refused, so reordering is tolerated within the window and nothing is
    accepted twice.

    Parameters
    ----------
    window : int
        Accepted counters remembered; a counter below the oldest of them is refused.
    """

    def __init__(self, window: int = REPLAY_WINDOW) -> None:
        self.window = int(window)
        self._order: Deque[int] = collections.deque()
        self._seen: Set[int] = set()
        self._floor = -1                       # the highest counter forgotten
        self.highest: Optional[int] = None

    def accept(self, counter: int) -> bool:
        """
        Check a counter and remember it.

        Parameters
        ----------
        counter : int
            The datagram's counter.

        Returns
        -------
        bool
            False for a replay (nothing is remembered then).
        """
        if counter in self._seen or counter <= self._floor:
            return False                       # seen, or not newer than one forgotten
        self._seen.add(counter)
        self._order.append(counter)
        if len(self._order) > self.window:
            old = self._order.popleft()
            self._seen.discard(old)
            self._floor = max(self._floor, old)
        if self.highest is None or counter > self.highest:
            self.highest = counter
        return True
