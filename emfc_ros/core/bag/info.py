"""
A ``ros2 bag info``-like summary of a bag, without ROS.

Reads ``metadata.yaml`` for files, duration and topics, optionally checks every chunk of the
storage files (CRCs; corrupt chunks listed with byte offset, time range and messages lost),
and optionally the block streams (sample rate, channels, samples, gaps) with
:func:`emfc_ros.core.bag.reader.read_streams`.
"""

from __future__ import annotations

import datetime
from pathlib import Path
from typing import List
import warnings

from emfc_ros.core.bag.metadata import read_metadata
from emfc_ros.core.bag.reader import BagDamageWarning, read_streams
from emfc_ros.core.bag.scan import data_section_crc_ok, McapScan


def _time(ns: int) -> str:
    stamp = datetime.datetime.fromtimestamp(ns * 1e-9, tz=datetime.timezone.utc)
    return f'{stamp:%Y-%m-%d %H:%M:%S.%f} UTC ({ns / 1e9:.9f})'


def _clock_note(clock: str) -> str:
    if clock == 'simulated':
        return ' of simulated time (stamps from /clock)'
    if clock == 'wall':
        return ' of wall time'
    return ''


def integrity_lines(bag: Path) -> List[str]:
    """
    Check every chunk of every storage file (CRCs included) and describe what was found.

    Parameters
    ----------
    bag : pathlib.Path
        The bag folder.

    Returns
    -------
    list of str
        ``Integrity: ...`` and one line per corrupt chunk or unfinished file.
    """
    from emfc_ros.core.bag.repair import storage_files
    chunks, problems = 0, []
    for name in storage_files(bag):
        scan = McapScan(bag / name, name, expand=False)
        for _ in scan.records():
            pass
        chunks += scan.chunks
        problems += [f'  {d.describe()}' for d in scan.damage]
        if not scan.complete:
            problems.append(f'  {name}: not finished ({scan.error}) after byte {scan.end_B}')
        if scan.magic_damaged:
            problems.append(f'  {name}: its leading magic bytes are damaged')
        if scan.summary_damaged:
            problems.append(f'  {name}: its summary or footer is damaged (the data section '
                            'was read without it)')
        with open(bag / name, 'rb') as handle:
            if not scan.damage and data_section_crc_ok(handle) is False:
                problems.append(f'  {name}: the data section fails its CRC (outside chunks)')
    if not problems:
        return [f'Integrity:         {chunks} chunks checked (CRC), all intact']
    return [f'Integrity:         DAMAGED, {chunks} chunks checked; run `emfc-bag-repair '
            f'{bag}` to rebuild it from the intact records:'] + problems


def bag_info(bag_path, streams: bool = False, check: bool = False) -> str:
    """
    Describe a bag for people.

    Parameters
    ----------
    bag_path : str or pathlib.Path
        The bag folder.
    streams : bool
        Also read the block streams and describe them (reads every block); implies
        ``check``.
    check : bool
        Also check every chunk's CRC and list the corrupt chunks.

    Returns
    -------
    str
        The summary text.

    Raises
    ------
    emfc_ros.core.bag.errors.BagFormatError
        If the bag cannot be read.
    """
    bag = Path(bag_path)
    meta = read_metadata(bag)
    files = meta.get('relative_file_paths') or []
    size = sum((bag / f).stat().st_size for f in files if (bag / f).is_file())
    start = int(meta['starting_time']['nanoseconds_since_epoch'])
    duration = int(meta['duration']['nanoseconds'])
    custom = meta.get('custom_data') or {}
    clock = str(custom.get('emfc_ros.clock', ''))
    lines: List[str] = [
        f'Files:             {", ".join(files)}',
        f'Bag size:          {size / 2**20:.3f} MiB',
        f'Storage id:        {meta.get("storage_identifier")}  (metadata version '
        f'{meta.get("version")})',
        f'Duration:          {duration / 1e9:.9f} s{_clock_note(clock)}',
        f'Start:             {_time(start)}',
        f'End:               {_time(start + duration)}',
        f'Messages:          {meta.get("message_count")}',
        'Topic information:']
    for entry in meta.get('topics_with_message_count') or []:
        t = entry['topic_metadata']
        lines.append(f'  Topic: {t["name"]} | Type: {t["type"]} | Count: '
                     f'{entry["message_count"]} | Serialization Format: '
                     f'{t["serialization_format"]}')
    if clock == 'simulated' and 'emfc_ros.start_time_ns' in custom:
        lines.insert(6, f'Recorded (wall):   {_time(int(custom["emfc_ros.start_time_ns"]))}')
    if custom:
        lines.append('Custom data:')
        for key in sorted(custom):
            first = str(custom[key]).splitlines()[0] if str(custom[key]) else ''
            more = f' ... ({len(str(custom[key]))} characters)' if '\n' in str(
                custom[key]) else ''
            lines.append(f'  {key}: {first}{more}')
    if check or streams:
        lines += integrity_lines(bag)
    if streams:
        lines.append('Block streams:')
        with warnings.catch_warnings():
            warnings.simplefilter('ignore', BagDamageWarning)  # listed under Integrity
            read = read_streams(bag, on_gap='nan')
        for key, s in read.items():
            channels = ', '.join(f'{n} [{u}]' for n, u in zip(s.channel_names,
                                                              s.channel_units))
            lines.append(f'  {key}: {s.sample_rate_Hz:g} Hz, epoch {s.epoch}, samples '
                         f'{s.first_sample_index} to {s.first_sample_index + s.n_samples - 1}'
                         f' ({s.n_samples / s.sample_rate_Hz:.6f} s), {len(s.gaps)} gaps '
                         f'({s.missing_samples} samples missing), {s.duplicates} duplicate '
                         f'blocks; channels: {channels}')
    return '\n'.join(lines)
