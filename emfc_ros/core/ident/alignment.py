"""
Measured channels on the excitation's sample clock, and the device faults that void them.

The plant simulator measures on the excitation's own clock (offset 0, no
``excitation_offset_samples`` in its description). The daq_bridge measures on the device's
clock from the device's start and publishes in its measurement description's ``extra`` the
device sample at which excitation sample 0 was applied (``excitation_offset_samples``, with
the excitation's ``excitation_epoch``) and its latched device faults (``faults``). A bag
(:mod:`~emfc_ros.core.ident.from_bag`) and data accumulated live by the identifier node
(:mod:`~emfc_ros.core.ident.live`) are cut and checked by the same functions, here.
"""

from __future__ import annotations

from typing import Any, Dict, Iterable, Mapping, Optional, Sequence

import numpy as np

from emfc_ros.core.ident.errors import IdentificationError


class DeviceFaultError(IdentificationError):
    """The device reported that the excitation was not applied as commanded."""


def excitation_offset(extra: Mapping[str, Any], excitation_epoch: Optional[int] = None,
                      namespace: str = '', during: str = 'the bag was recording') -> int:
    """
    Device sample index at which excitation sample 0 was applied.

    Parameters
    ----------
    extra : mapping
        The measurement description's ``extra``.
    excitation_epoch : int, optional
        Epoch of the excitation the data answer, to check that the offset belongs to it.
    namespace : str
        For messages.
    during : str
        What was going on while the data were taken, for messages.

    Returns
    -------
    int
        The offset [samples]: measurement ``k + offset`` responds to excitation ``k``; 0
        when the description has no ``excitation_offset_samples`` (the measurements are on
        the excitation's clock).

    Raises
    ------
    IdentificationError
        If the description says there is an offset but it is unknown (the bridge received no
        excitation) or it belongs to another excitation epoch.
    """
    if 'excitation_offset_samples' not in extra:
        return 0
    offset = extra['excitation_offset_samples']
    if offset is None:
        raise IdentificationError(f'{namespace}/measurements/description has no excitation '
                                  'offset (excitation_offset_samples is null): the bridge did '
                                  f'not receive excitation while {during}')
    epoch = extra.get('excitation_epoch')
    if excitation_epoch is not None and epoch is not None and int(epoch) != excitation_epoch:
        raise IdentificationError(f'the excitation offset of {namespace}/measurements belongs '
                                  f'to excitation epoch {epoch}, the excitation of the data is '
                                  f'epoch {excitation_epoch}')
    return int(offset)


def experiment_samples(sections: Iterable[Mapping[str, Any]], at_least: int = 0) -> int:
    """
    Samples of the experiment a section table describes.

    Parameters
    ----------
    sections : iterable of mapping
        The excitation description's section table (``first_sample_index``, ``n_samples``).
    at_least : int
        A lower bound from elsewhere (the end of the recorded excitation) [samples].

    Returns
    -------
    int
        The end of the last section, or ``at_least`` when larger.
    """
    return max([int(s['first_sample_index']) + int(s['n_samples']) for s in sections]
               + [int(at_least)])


def align(channels: Mapping[str, np.ndarray], first_index: int, offset: int,
          n_samples: Optional[int] = None, namespace: str = '') -> Dict[str, np.ndarray]:
    """
    The measured channels on the excitation's sample clock.

    Parameters
    ----------
    channels : mapping of str to ndarray
        Channel name to a 1-D record whose element 0 is measurement sample ``first_index``
        (all of one length).
    first_index : int
        Measurement sample index of the records' first element.
    offset : int
        Measurement sample of excitation sample 0 (:func:`excitation_offset`).
    n_samples : int, optional
        Samples wanted from there (the experiment's length); None: to the end of the records.
    namespace : str
        For messages.

    Returns
    -------
    dict of str to ndarray
        Channel name to a view whose index ``k`` is excitation sample ``k``.

    Raises
    ------
    IdentificationError
        If the records do not cover the experiment.
    """
    available = min((len(v) for v in channels.values()), default=0)
    start = int(offset) - int(first_index)
    if start < 0:
        raise IdentificationError(f'{namespace}/measurements starts at sample {first_index}, '
                                  f'after the experiment began (sample {offset}): the start '
                                  'of the experiment was not recorded')
    stop = available if n_samples is None else start + int(n_samples)
    if stop > available:
        raise IdentificationError(f'{namespace}/measurements ends at sample '
                                  f'{first_index + available}, before the end of the '
                                  f'experiment (sample {offset + int(n_samples)})')
    return {name: values[start:stop] for name, values in channels.items()}


def refuse_faults(faults: Sequence[Any], offset: int, n_samples: int,
                  sample_rate_Hz: float) -> None:
    """
    Refuse data whose device reported that the excitation was not applied as commanded.

    Parameters
    ----------
    faults : sequence of Fault
        The device's faults (:class:`~emfc_ros.core.device.faults.Fault`), duplicates
        allowed.
    offset : int
        Device sample of excitation sample 0.
    n_samples : int
        Samples of the experiment.
    sample_rate_Hz : float
        For the message [Hz].

    Raises
    ------
    DeviceFaultError
        If a fault touches the experiment's samples or its position is unknown.
    """
    from emfc_ros.core.device.faults import describe

    hits = []
    for fault in dict.fromkeys(faults):
        span = fault.experiment_range(offset, n_samples)
        if span is None or span[1] > span[0]:
            hits.append(fault)
    if hits:
        raise DeviceFaultError(
            'the device did not apply the excitation as commanded during this experiment, '
            'so the data do not answer it; repeat the experiment:\n  '
            + describe(hits, offset, n_samples, sample_rate_Hz).replace('\n', '\n  '))
