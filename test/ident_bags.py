"""
Bags of simulated identification experiments, written with the project's own bag writer.

:func:`write_experiment_bag` stores a recording (e.g. an
:class:`~emfc_ros.core.ident.offnominal.OffNominalRecord`'s, possibly broken on purpose) in
the documented format the runner records: ``<ns>/measurements`` blocks with their description,
``<ns>/excitation`` blocks with the section table in their description; messages serialised by
rosbags' typestore, as the recorder stores what it receives.
"""

from pathlib import Path
from typing import Any, Mapping, Optional, Sequence

import numpy as np
from rosbags.typesys import get_typestore, Stores
import yaml

from emfc_ros.core.bag import BagWriter, OfferedQos
from emfc_ros.core.blocks import Channel, pack, StreamDescription

TS = get_typestore(Stores.ROS2_JAZZY)
F64 = 'std_msgs/msg/Float64MultiArray'
STR = 'std_msgs/msg/String'
UNITS = {'_V': 'V', '_A': 'A', '_m': 'm', '_N': 'N'}


def _block(first: int, rate: float, samples: np.ndarray) -> bytes:
    t = TS.types
    dim = t['std_msgs/msg/MultiArrayDimension']
    layout = t['std_msgs/msg/MultiArrayLayout'](dim=[
        dim('channel', samples.shape[0], samples.size),
        dim('sample', samples.shape[1], samples.shape[1])], data_offset=3)
    return TS.serialize_cdr(t[F64](layout=layout, data=pack(first, rate, 1, samples)), F64)


def _text(text: str) -> bytes:
    return TS.serialize_cdr(TS.types[STR](data=text), STR)


def _unit(name: str) -> str:
    return next((u for suffix, u in UNITS.items() if name.endswith(suffix)), '')


def write_experiment_bag(path: Path, channels: Mapping[str, np.ndarray], sample_rate_Hz: float,
                         sections: Sequence[Sequence[Any]], namespace: str = '/emfc',
                         extra: Optional[Mapping[str, Any]] = None,
                         custom_data: Optional[Mapping[str, Any]] = None,
                         block_size: int = 10000, excitation_blocks: bool = True,
                         excitation_description: bool = True) -> Path:
    """
    Write a recorded experiment as a bag.

    Parameters
    ----------
    path : pathlib.Path
        The bag folder (created).
    channels : mapping of str to ndarray
        The measured channels on one clock (names with their unit suffix).
    sample_rate_Hz : float
        Sample rate [Hz].
    sections : sequence of (name, first_sample_index, n_samples)
        The section table.
    namespace : str
        Streams' namespace.
    extra : mapping, optional
        The measurement description's ``extra`` (e.g. the pan load, as a plant simulator
        publishes it); default none.
    custom_data : mapping, optional
        Metadata ``custom_data`` entries (values dumped as YAML).
    block_size : int
        Samples per block.
    excitation_blocks, excitation_description : bool
        Whether the excitation's blocks and its description (the section table) are in the
        bag (a recording of the measurements alone leaves out the blocks).

    Returns
    -------
    pathlib.Path
        The bag folder.
    """
    names = list(channels)
    data = np.vstack([np.asarray(channels[n], dtype=float) for n in names])
    n = data.shape[1]
    writer = BagWriter(path)
    writer.open()
    meas = writer.add_connection(f'{namespace}/measurements', F64, [OfferedQos()])
    meas_d = writer.add_connection(f'{namespace}/measurements/description', STR, [OfferedQos()])
    exc = writer.add_connection(f'{namespace}/excitation', F64, [OfferedQos()]) \
        if excitation_blocks else None
    exc_d = writer.add_connection(f'{namespace}/excitation/description', STR,
                                  [OfferedQos()]) if excitation_description else None
    table = [{'name': s[0], 'first_sample_index': int(s[1]), 'n_samples': int(s[2])}
             for s in sections]
    writer.write(meas_d, 1, _text(StreamDescription(
        'measurements', sample_rate_Hz, block_size,
        tuple(Channel(c, _unit(c)) for c in names), epoch=1, total_samples=n,
        source='/test_writer', extra=dict(extra or {})).to_json()))
    if exc_d is not None:
        writer.write(exc_d, 2, _text(StreamDescription(
            'excitation', sample_rate_Hz, block_size,
            (Channel('coil', 'V'), Channel('load_changer', 'V')),
            epoch=1, total_samples=n, source='/test_writer',
            extra={'sections': table}).to_json()))
    setpoints = np.vstack([channels['coil_setpoint_V'], channels['load_changer_setpoint_V']])
    t = 3
    for first in range(0, n, block_size):
        stop = min(first + block_size, n)
        if exc is not None:
            writer.write(exc, t, _block(first, sample_rate_Hz, setpoints[:, first:stop]))
        writer.write(meas, t + 1, _block(first, sample_rate_Hz, data[:, first:stop]))
        t += 2
    for key, value in (custom_data or {}).items():
        writer.set_custom_data(key, yaml.safe_dump(value))
    writer.close()
    return path
