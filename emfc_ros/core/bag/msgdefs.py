"""
Message definitions and type hashes for MCAP schemas, from a pinned rosbags typestore.

The typestore is ``Stores.ROS2_JAZZY`` (every standard interface of Jazzy). Types it does
not know are looked up as ``<prefix>/share/<package>/msg/<Name>.msg`` below the given
prefixes (for example those of ``AMENT_PREFIX_PATH``) and registered on first use.
"""

from __future__ import annotations

from pathlib import Path
import re
from typing import Dict, Optional, Sequence, Tuple

from rosbags.typesys import get_types_from_msg, get_typestore, Stores

from emfc_ros.core.errors import EmfcError

_FIELD_TYPE = re.compile(r'^\s*([A-Za-z_][\w]*/[A-Za-z_]\w*)(\[[^\]]*\])?\s+\w', re.M)


class MessageTypeError(EmfcError, LookupError):
    """A message type has no definition in the typestore or in any share/ folder."""


class MessageTypes:
    """
    Message definitions (``ros2msg`` text) and RIHS01 hashes of ROS 2 message types.

    Parameters
    ----------
    prefixes : sequence of str or Path, optional
        Install prefixes searched for ``share/<pkg>/msg/<Name>.msg`` of unknown types.
    """

    def __init__(self, prefixes: Sequence = ()) -> None:
        self.typestore = get_typestore(Stores.ROS2_JAZZY)
        self._prefixes = [Path(p) for p in prefixes if str(p)]
        self._cache: Dict[str, Tuple[str, str]] = {}

    def definition(self, msgtype: str) -> Tuple[str, str]:
        """
        The message definition and type hash of a type.

        Parameters
        ----------
        msgtype : str
            Type name such as ``'std_msgs/msg/Float64MultiArray'``.

        Returns
        -------
        tuple of str
            ``(ros2msg definition text, 'RIHS01_...' hash)``.

        Raises
        ------
        MessageTypeError
            If the type is unknown and no ``.msg`` file defines it.
        """
        if msgtype not in self._cache:
            if msgtype not in self.typestore.fielddefs:
                self._register(msgtype, set())
            msgdef, _ = self.typestore.generate_msgdef(msgtype, ros_version=2)
            self._cache[msgtype] = (msgdef, self.typestore.hash_rihs01(msgtype))
        return self._cache[msgtype]

    def _register(self, msgtype: str, seen: set) -> None:
        if msgtype in self.typestore.fielddefs or msgtype in seen:
            return
        seen.add(msgtype)
        path = self._find(msgtype)
        if path is None:
            raise MessageTypeError(
                f'message type {msgtype!r} is not in the ROS 2 Jazzy typestore and no '
                f'share/<package>/msg/<Name>.msg defines it')
        text = path.read_text()
        for match in _FIELD_TYPE.finditer(text):
            dep = match.group(1)
            pkg, name = dep.split('/')
            self._register(f'{pkg}/msg/{name}', seen)
        self.typestore.register(get_types_from_msg(text, msgtype))

    def _find(self, msgtype: str) -> Optional[Path]:
        parts = msgtype.split('/')
        if len(parts) != 3:
            return None
        package, kind, name = parts
        for prefix in self._prefixes:
            path = prefix / 'share' / package / kind / f'{name}.msg'
            if path.is_file():
                return path
        return None
