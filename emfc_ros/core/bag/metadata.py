"""
The rosbag2 ``metadata.yaml`` (version 9) of a bag folder: build, write atomically, read.

The layout is the one ``ros2 bag record`` writes with the MCAP storage plugin, so that
``ros2 bag info`` and ``ros2 bag play`` open the folder on a full ROS 2 install.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Sequence

import yaml

from emfc_ros.core.bag.errors import BagFormatError
from emfc_ros.core.safe_yaml import load_yaml_file, one_line, YamlRefused

METADATA_FILE = 'metadata.yaml'
VERSION = 9
STORAGE_IDENTIFIER = 'mcap'


@dataclasses.dataclass
class FileStats:
    """
    One storage file of a bag.

    Attributes
    ----------
    path : str
        File name relative to the bag folder.
    start_ns : int
        Earliest message timestamp [ns] (0 when empty).
    end_ns : int
        Latest message timestamp [ns].
    message_count : int
        Messages in the file.
    """

    path: str
    start_ns: int = 0
    end_ns: int = 0
    message_count: int = 0

    def add(self, timestamp_ns: int) -> None:
        """
        Count one message.

        Parameters
        ----------
        timestamp_ns : int
            Its timestamp [ns].
        """
        if self.message_count == 0:
            self.start_ns = self.end_ns = timestamp_ns
        else:
            self.start_ns = min(self.start_ns, timestamp_ns)
            self.end_ns = max(self.end_ns, timestamp_ns)
        self.message_count += 1


@dataclasses.dataclass
class TopicStats:
    """
    One topic (connection) of a bag.

    Attributes
    ----------
    name : str
        Topic name.
    msgtype : str
        Message type, for example ``'std_msgs/msg/String'``.
    offered_qos_profiles : list of dict
        As :func:`emfc_ros.core.bag.qos.qos_list` returns.
    type_description_hash : str
        ``'RIHS01_...'``.
    message_count : int
        Messages recorded.
    serialization_format : str
        ``'cdr'``.
    """

    name: str
    msgtype: str
    offered_qos_profiles: list = dataclasses.field(default_factory=list)
    type_description_hash: str = ''
    message_count: int = 0
    serialization_format: str = 'cdr'


def build_metadata(files: Sequence[FileStats], topics: Sequence[TopicStats],
                   custom_data: Optional[Mapping[str, str]] = None,
                   ros_distro: str = 'jazzy') -> Dict[str, Any]:
    """
    The content of ``metadata.yaml``.

    Parameters
    ----------
    files : sequence of FileStats
        The storage files, in order.
    topics : sequence of TopicStats
        The topics.
    custom_data : Mapping, optional
        String to string map stored under ``custom_data``.
    ros_distro : str
        Stored under ``ros_distro``.

    Returns
    -------
    dict
        ``{'rosbag2_bagfile_information': {...}}``.
    """
    counted = [f for f in files if f.message_count]
    start = min((f.start_ns for f in counted), default=0)
    end = max((f.end_ns for f in counted), default=0)
    info = {
        'version': VERSION,
        'storage_identifier': STORAGE_IDENTIFIER,
        'duration': {'nanoseconds': int(end - start)},
        'starting_time': {'nanoseconds_since_epoch': int(start)},
        'message_count': int(sum(f.message_count for f in files)),
        'topics_with_message_count': [
            {'topic_metadata': {'name': t.name, 'type': t.msgtype,
                                'serialization_format': t.serialization_format,
                                'offered_qos_profiles': list(t.offered_qos_profiles),
                                'type_description_hash': t.type_description_hash},
             'message_count': int(t.message_count)}
            for t in topics],
        'compression_format': '',
        'compression_mode': '',
        'relative_file_paths': [f.path for f in files],
        'files': [{'path': f.path,
                   'starting_time': {'nanoseconds_since_epoch': int(f.start_ns)},
                   'duration': {'nanoseconds': int(f.end_ns - f.start_ns)},
                   'message_count': int(f.message_count)} for f in files],
        'custom_data': {str(k): str(v) for k, v in (custom_data or {}).items()} or None,
        'ros_distro': ros_distro,
    }
    return {'rosbag2_bagfile_information': info}


def dump_metadata(metadata: Mapping[str, object]) -> str:
    """
    The YAML text of a metadata mapping.

    Parameters
    ----------
    metadata : Mapping
        As :func:`build_metadata` returns.

    Returns
    -------
    str
        Block-style YAML in rosbag2's key order.
    """
    return yaml.safe_dump(dict(metadata), default_flow_style=False, sort_keys=False,
                          allow_unicode=True, width=1 << 16)


def write_metadata(folder: Path, metadata: Mapping[str, object]) -> Path:
    """
    Write ``metadata.yaml`` atomically (temporary file, then rename).

    Parameters
    ----------
    folder : pathlib.Path
        The bag folder.
    metadata : Mapping
        As :func:`build_metadata` returns.

    Returns
    -------
    pathlib.Path
        The file written.

    Raises
    ------
    OSError
        If the file cannot be written.
    """
    path = Path(folder) / METADATA_FILE
    tmp = path.with_suffix('.yaml.tmp')
    with open(tmp, 'w', encoding='utf-8') as handle:
        handle.write(dump_metadata(metadata))
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(tmp, path)
    return path


def read_metadata(folder: Path) -> Dict[str, Any]:
    """
    Read the ``rosbag2_bagfile_information`` of a bag folder.

    Parameters
    ----------
    folder : pathlib.Path
        The bag folder.

    Returns
    -------
    dict
        The inner mapping.

    Raises
    ------
    BagFormatError
        If the file is missing or is not rosbag2 metadata.
    """
    path = Path(folder) / METADATA_FILE
    try:
        doc = load_yaml_file(path)
    except YamlRefused as exc:
        raise BagFormatError(str(exc)) from exc
    except (OSError, yaml.YAMLError) as exc:
        raise BagFormatError(f'cannot read {path}: {one_line(exc)}') from exc
    if not isinstance(doc, dict) or not isinstance(
            doc.get('rosbag2_bagfile_information'), dict):
        raise BagFormatError(f'{path} has no rosbag2_bagfile_information mapping')
    return doc['rosbag2_bagfile_information']


def custom_data(folder: Path) -> Dict[str, str]:
    """
    The ``custom_data`` map of a bag.

    Parameters
    ----------
    folder : pathlib.Path
        The bag folder.

    Returns
    -------
    dict
        Keys and values (empty when there is none).
    """
    return dict(read_metadata(folder).get('custom_data') or {})


def file_list(folder: Path) -> List[str]:
    """
    The storage files named in ``metadata.yaml``.

    Parameters
    ----------
    folder : pathlib.Path
        The bag folder.

    Returns
    -------
    list of str
        ``relative_file_paths``.
    """
    return [str(p) for p in read_metadata(folder).get('relative_file_paths') or []]
