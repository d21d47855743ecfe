"""
Repair a bag: recover every intact MCAP record, rebuild metadata.yaml.

A recorder killed while writing leaves its last MCAP file without summary and footer (and
possibly a partly written chunk); a damaged disk or copy leaves chunks whose CRC does not
match. :func:`repair_bag` checks every chunk's CRC of every storage file
(:mod:`emfc_ros.core.bag.scan`); a file that is truncated or has a corrupt chunk is read
record by record (the corrupt chunks skipped, reading stops at a truncation), its intact
records are rewritten as a valid MCAP file with summary, the original is kept as
``<file>.damaged`` (unless asked not to), and the report says what was lost (messages,
seconds of log time, byte offsets). ``metadata.yaml`` is rebuilt from all storage files,
keeping the ``custom_data`` of the provisional metadata the recorder wrote (as ``ros2 bag
reindex`` rebuilds it). Intact files are only read, never rewritten; repairing a good bag
changes nothing but the metadata's layout.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
import re
import struct
from typing import Dict, List, Optional, Set, Tuple

from mcap.records import Channel, Message, Metadata, Schema
from mcap.writer import CompressionType, Writer as McapWriter
import yaml

from emfc_ros.core.bag.errors import BagFormatError
from emfc_ros.core.bag.metadata import (
    build_metadata, FileStats, METADATA_FILE, read_metadata, TopicStats, write_metadata)
from emfc_ros.core.bag.scan import (ChunkDamage, data_section_crc_ok, McapScan, read_header,
                                    read_summary)
from emfc_ros.core.bag.writer import LIBRARY, PROFILE
from emfc_ros.core.safe_yaml import load_yaml_text, YamlRefused

_SPLIT_INDEX = re.compile(r'_(\d+)\.mcap$')


@dataclasses.dataclass
class FileReport:
    """
    What repair found in one storage file.

    Attributes
    ----------
    path : str
        File name in the bag folder.
    status : str
        ``'ok'`` (intact) or ``'recovered'`` (rewritten from its intact records).
    message_count : int
        Messages in the (repaired) file.
    lost_bytes : int
        Bytes that could not be recovered: after the last complete record, and in corrupt
        chunks [B].
    error : str
        Why the original could not be read to its end ('' if it could).
    damage : list of ChunkDamage
        The corrupt chunks skipped.
    """

    path: str
    status: str
    message_count: int
    lost_bytes: int = 0
    error: str = ''
    damage: List[ChunkDamage] = dataclasses.field(default_factory=list)

    @property
    def lost_messages(self) -> int:
        """
        Messages lost in corrupt chunks (as their message indexes count them).

        Returns
        -------
        int
            The sum over the corrupt chunks whose count is known.
        """
        return sum(d.message_count or 0 for d in self.damage)

    @property
    def lost_s(self) -> float:
        """
        Log time spanned by the corrupt chunks [s].

        Returns
        -------
        float
            The sum of their spans.
        """
        return sum(d.duration_s for d in self.damage)


@dataclasses.dataclass
class RepairReport:
    """
    The result of :func:`repair_bag`.

    Attributes
    ----------
    bag : pathlib.Path
        The bag folder.
    files : list of FileReport
        One per storage file.
    metadata : dict
        The rebuilt ``rosbag2_bagfile_information``.
    """

    bag: Path
    files: List[FileReport]
    metadata: dict

    @property
    def repaired(self) -> bool:
        """
        Whether any file had to be rewritten.

        Returns
        -------
        bool
            True if a file was recovered.
        """
        return any(f.status == 'recovered' for f in self.files)

    @property
    def message_count(self) -> int:
        """
        Messages in the repaired bag.

        Returns
        -------
        int
            The sum over files.
        """
        return sum(f.message_count for f in self.files)

    def summary(self) -> str:
        """
        A few lines for people.

        Returns
        -------
        str
            One line per file and a total.
        """
        lines = [f'{self.bag}:']
        for f in self.files:
            extra = ''
            if f.status == 'recovered' and f.damage:
                extra = (f' ({len(f.damage)} corrupt chunks skipped: {f.lost_messages} '
                         f'messages, {f.lost_s:.6f} s of log time lost'
                         + (f'; then {f.error}' if f.error else '') + ')')
            elif f.status == 'recovered' and f.error:
                extra = f' (lost {f.lost_bytes} B after the last complete record: {f.error})'
            elif f.status == 'recovered':
                extra = ' (rewritten: damage outside the chunks, no message lost)'
            lines.append(f'  {f.path}: {f.status}, {f.message_count} messages{extra}')
            lines.extend(f'    {d.describe()}' for d in f.damage)
        lost = sum(f.lost_messages for f in self.files)
        more = (f'; {lost} messages ({sum(f.lost_s for f in self.files):.6f} s) lost in '
                f'corrupt chunks' if any(f.damage for f in self.files) else '')
        lines.append(f'  total {self.message_count} messages{more}; metadata.yaml rebuilt')
        return '\n'.join(lines)


class _TopicTable:
    """Topics across files, keyed by (topic, type)."""

    def __init__(self) -> None:
        self.topics: Dict[Tuple[str, str], TopicStats] = {}

    def add(self, channel: Channel, schema: Optional[Schema], count: int) -> None:
        msgtype = schema.name if schema is not None else ''
        key = (channel.topic, msgtype)
        stats = self.topics.get(key)
        if stats is None:
            qos_text = channel.metadata.get('offered_qos_profiles', '')
            try:
                qos = load_yaml_text(qos_text, f'{channel.topic} offered_qos_profiles') \
                    if qos_text else []
            except (yaml.YAMLError, YamlRefused):
                qos = []
            stats = self.topics[key] = TopicStats(
                name=channel.topic, msgtype=msgtype,
                offered_qos_profiles=qos if isinstance(qos, list) else [],
                type_description_hash=channel.metadata.get('topic_type_hash', ''),
                serialization_format=channel.message_encoding or 'cdr')
        stats.message_count += count


def storage_files(bag: Path) -> List[str]:
    """
    The MCAP files of a bag folder: those named in metadata.yaml plus any other ``*.mcap``.

    Parameters
    ----------
    bag : pathlib.Path
        The bag folder.

    Returns
    -------
    list of str
        File names in split order (``<name>_0.mcap``, ``<name>_1.mcap``, ...).
    """
    names: Set[str] = set()
    try:
        names.update(read_metadata(bag).get('relative_file_paths') or [])
    except BagFormatError:
        pass
    names.update(p.name for p in bag.glob('*.mcap'))
    names = {n for n in names if (bag / n).is_file()}

    def order(name: str):
        match = _SPLIT_INDEX.search(name)
        return (int(match.group(1)) if match else -1, name)

    return sorted(names, key=order)


def _intact(path: Path):
    """Return the summary of an intact MCAP file (data section or every chunk CRC), or None."""
    try:
        with open(path, 'rb') as handle:
            summary = read_summary(handle)
            data_ok = data_section_crc_ok(handle) if summary is not None else None
            header = read_header(handle)
    except (OSError, struct.error):
        return None
    if summary is None or data_ok is False or header is None or header.profile != PROFILE:
        return None
    if data_ok:
        return summary
    scan = McapScan(path, path.name, expand=False)
    for _ in scan.records():
        pass
    return summary if scan.complete and not scan.damage else None


def _recover(path: Path, out: Path, table: _TopicTable, stats: FileStats,
             custom: Dict[str, str]) -> Tuple[int, str, List[ChunkDamage]]:
    """Write the intact records of ``path`` into a new MCAP ``out``: (end, error, damage)."""
    schemas: Dict[int, Schema] = {}
    channels: Dict[int, Channel] = {}
    counts: Dict[int, int] = {}
    new_schema: Dict[int, int] = {}
    new_channel: Dict[int, int] = {}
    scan = McapScan(path, path.name)
    with open(out, 'xb') as dst:
        writer = McapWriter(dst, compression=CompressionType.NONE, enable_data_crcs=True)
        writer.start(PROFILE, LIBRARY)
        try:
            for record in scan.records():
                if isinstance(record, Schema):
                    if record.id not in new_schema:
                        schemas[record.id] = record
                        new_schema[record.id] = writer.register_schema(
                            record.name, record.encoding, record.data)
                elif isinstance(record, Channel):
                    if record.id not in new_channel:
                        channels[record.id] = record
                        new_channel[record.id] = writer.register_channel(
                            record.topic, record.message_encoding,
                            new_schema.get(record.schema_id, 0), dict(record.metadata))
                elif isinstance(record, Message):
                    if record.channel_id not in new_channel:
                        continue
                    writer.add_message(new_channel[record.channel_id], record.log_time,
                                       record.data, record.publish_time, record.sequence)
                    counts[record.channel_id] = counts.get(record.channel_id, 0) + 1
                    stats.add(record.log_time)
                elif isinstance(record, Metadata) and record.name == 'rosbag2':
                    custom.update(_custom_from_record(record))
            error = scan.error
        except Exception as exc:  # a record that parses but is damaged: stop there
            error = f'{type(exc).__name__}: {exc}' if str(exc) else type(exc).__name__
        writer.finish()
        dst.flush()
        os.fsync(dst.fileno())
    for cid, channel in channels.items():
        table.add(channel, schemas.get(channel.schema_id), counts.get(cid, 0))
    if not scan.complete and not error:
        error = 'truncated'
    return scan.end_B, error, scan.damage


def _custom_from_record(record: Metadata) -> Dict[str, str]:
    try:
        doc = load_yaml_text(record.metadata.get('serialized_metadata', ''),
                             'the rosbag2 metadata record')
        return {str(k): str(v) for k, v in (doc.get('custom_data') or {}).items()}
    except (yaml.YAMLError, YamlRefused, AttributeError):
        return {}


def repair_bag(bag_path, keep_damaged: bool = True) -> RepairReport:
    """
    Make a bag whose recorder died, or whose files have corrupt chunks, readable again.

    Parameters
    ----------
    bag_path : str or pathlib.Path
        The bag folder.
    keep_damaged : bool
        Keep each rewritten original as ``<file>.damaged``; delete it when False.

    Returns
    -------
    RepairReport
        What was found and done.

    Raises
    ------
    BagFormatError
        If the folder does not exist or holds no MCAP file.
    """
    bag = Path(bag_path)
    if not bag.is_dir():
        raise BagFormatError(f'{bag} is not a bag folder')
    names = storage_files(bag)
    if not names:
        raise BagFormatError(f'{bag} holds no .mcap file')
    custom: Dict[str, str] = {}
    ros_distro = 'jazzy'
    try:
        old = read_metadata(bag)
        custom.update({str(k): str(v) for k, v in (old.get('custom_data') or {}).items()})
        ros_distro = str(old.get('ros_distro') or ros_distro)
    except BagFormatError:
        pass
    from_files: Dict[str, str] = {}
    table = _TopicTable()
    files: List[FileStats] = []
    reports: List[FileReport] = []
    for name in names:
        path = bag / name
        stats = FileStats(name)
        summary = _intact(path)
        if summary is not None:
            st = summary.statistics
            stats.message_count = st.message_count
            if st.message_count:
                stats.start_ns, stats.end_ns = st.message_start_time, st.message_end_time
            for cid, channel in summary.channels.items():
                table.add(channel, summary.schemas.get(channel.schema_id),
                          st.channel_message_counts.get(cid, 0))
            reports.append(FileReport(name, 'ok', st.message_count))
        else:
            tmp = path.with_name(name + '.repair.tmp')
            if tmp.exists():
                tmp.unlink()
            good_end, error, damage = _recover(path, tmp, table, stats, from_files)
            lost = path.stat().st_size - good_end + sum(d.length_B for d in damage)
            if keep_damaged:
                os.replace(path, path.with_name(name + '.damaged'))
            os.replace(tmp, path)
            reports.append(FileReport(name, 'recovered', stats.message_count, lost, error,
                                      damage))
        files.append(stats)
    for key, value in from_files.items():
        custom.setdefault(key, value)
    metadata = build_metadata(files, list(table.topics.values()), custom, ros_distro)
    write_metadata(bag, metadata)
    return RepairReport(bag, reports, metadata['rosbag2_bagfile_information'])


__all__ = ['FileReport', 'METADATA_FILE', 'repair_bag', 'RepairReport', 'storage_files']
