"""
Message accounting per recorded stream: due, published, decimated, recorded, lost.

No silent loss (issue 13): a run says, per stream it publishes, how many messages the
experiment called for (``due``), how many its publisher sent (``published``, of which
``repeated`` were sent again: no loss), how many a documented rate limit left out
(``decimated``: the plant simulator's wall-rate limit on ``joint_states`` in owner mode) and
how many the bag holds (``recorded``); ``lost`` is what was published but is not in the bag
(dropped by DDS or by the recorder's queue). The counts add up when
``published - repeated + decimated == due`` and ``lost == 0``; :func:`problems` names every
stream where they do not. The runner writes the table to ``summary.md`` and, as YAML, to the
bag's custom data ``emfc_ros.stream_counts``.
"""

from __future__ import annotations

import dataclasses
from typing import Dict, Iterable, List, Mapping, Optional

import yaml

#: The bag's custom data key of the accounting.
CUSTOM_DATA_KEY = 'emfc_ros.stream_counts'


@dataclasses.dataclass(frozen=True)
class StreamCount:
    """
    What happened to one stream's messages [count].

    Attributes
    ----------
    topic : str
        Fully qualified topic name.
    recorded : int
        Messages in the bag.
    published : int or None
        Messages the publisher sent (``repeated`` included); None when no node of the run
        counts them (a topic of another publisher).
    repeated : int
        Messages sent again (the signal generator re-sends a window that was not acknowledged
        in time): no loss, and not due twice.
    decimated : int
        Messages due but left out by a documented rate limit.
    due : int or None
        Messages the experiment called for; None when the experiment does not define it.
    """

    topic: str
    recorded: int
    published: Optional[int] = None
    repeated: int = 0
    decimated: int = 0
    due: Optional[int] = None

    @property
    def lost(self) -> Optional[int]:
        """
        Published but not in the bag (None when nobody counted what was published).

        Returns
        -------
        int or None
            ``published - recorded``.
        """
        return None if self.published is None else self.published - self.recorded

    def as_dict(self) -> Dict[str, Optional[int]]:
        """
        The counts as a mapping (the custom data form).

        Returns
        -------
        dict
            ``due``, ``published``, ``repeated``, ``decimated``, ``recorded``, ``lost``.
        """
        return {'due': self.due, 'published': self.published, 'repeated': self.repeated,
                'decimated': self.decimated, 'recorded': self.recorded, 'lost': self.lost}


def states_due(block_sizes: Iterable[int], sample_rate_Hz: float,
               state_rate_Hz: float) -> int:
    """
    Joint states an owner-mode simulator owes for the blocks it answered.

    The simulator publishes the state at the samples 0, k, 2k, ... of the sample index (the
    device contract's grid, :func:`emfc_ros.core.device_contract.state_sample_offsets`),
    ``k = round(sample_rate_Hz / state_rate_Hz)``; the blocks follow each other from sample 0.

    Parameters
    ----------
    block_sizes : iterable of int
        Samples per answered block [samples].
    sample_rate_Hz : float
        Sample rate [Hz].
    state_rate_Hz : float
        Joint state rate [Hz]; 0 or less: none.

    Returns
    -------
    int
        Joint states due [count].
    """
    if state_rate_Hz <= 0.0:
        return 0
    step = max(1, int(round(sample_rate_Hz / state_rate_Hz)))
    return -(-sum(int(n) for n in block_sizes) // step)


def problems(counts: Iterable[StreamCount]) -> List[str]:
    """
    Every stream whose counts do not add up.

    Parameters
    ----------
    counts : iterable of StreamCount
        The accounting.

    Returns
    -------
    list of str
        One line per problem (lost messages; published and decimated not adding up to
        what was due); empty when everything published is in the bag.
    """
    out = []
    for c in counts:
        if c.lost:
            what = 'lost' if c.lost > 0 else 'more recorded than published'
            out.append(f'{c.topic}: {abs(c.lost)} {what} ({c.published} published, '
                       f'{c.recorded} recorded)')
        if c.due is not None and c.published is not None and \
                c.published - c.repeated + c.decimated != c.due:
            out.append(f'{c.topic}: {c.published} published - {c.repeated} repeated + '
                       f'{c.decimated} decimated != {c.due} due')
    return out


def to_yaml(counts: Iterable[StreamCount]) -> str:
    """
    The accounting as the bag's custom data text.

    Parameters
    ----------
    counts : iterable of StreamCount
        The accounting.

    Returns
    -------
    str
        YAML: topic to ``{due, published, repeated, decimated, recorded, lost}``.
    """
    return yaml.safe_dump({c.topic: c.as_dict() for c in counts}, sort_keys=False)


def from_mapping(doc: Mapping[str, Mapping[str, Optional[int]]]) -> List[StreamCount]:
    """
    Read the accounting back from its custom data form.

    Parameters
    ----------
    doc : Mapping
        Topic to counts, as :func:`to_yaml` writes it.

    Returns
    -------
    list of StreamCount
        The accounting.

    Raises
    ------
    ValueError
        If an entry lacks ``recorded`` or holds something other than integers.
    """
    out = []
    for topic, entry in doc.items():
        if not isinstance(entry, Mapping) or not isinstance(entry.get('recorded'), int):
            raise ValueError(f'{CUSTOM_DATA_KEY}: {topic}: no integer `recorded` count')
        values = {k: entry.get(k) for k in ('published', 'due')}
        values.update({k: entry.get(k, 0) for k in ('repeated', 'decimated')})
        for key, value in values.items():
            if value is not None and (not isinstance(value, int) or isinstance(value, bool)):
                raise ValueError(f'{CUSTOM_DATA_KEY}: {topic}: {key} must be an integer, '
                                 f'got {value!r}')
        out.append(StreamCount(str(topic), entry['recorded'], values['published'],
                               int(values['repeated'] or 0), int(values['decimated'] or 0),
                               values['due']))
    return out


def markdown(counts: Iterable[StreamCount]) -> List[str]:
    """
    The accounting as a Markdown table and a verdict line.

    Parameters
    ----------
    counts : iterable of StreamCount
        The accounting.

    Returns
    -------
    list of str
        Lines for ``summary.md``.
    """
    counts = list(counts)

    def cell(value: Optional[int]) -> str:
        return '-' if value is None else str(value)

    lines = ['| stream | due | published | repeated | decimated | recorded | lost |',
             '|---|---|---|---|---|---|---|']
    lines += [f'| `{c.topic}` | {cell(c.due)} | {cell(c.published)} | {c.repeated} | '
              f'{c.decimated} | {c.recorded} | {cell(c.lost)} |' for c in counts]
    found = problems(counts)
    decimated = sum(c.decimated for c in counts)
    if found:
        lines += ['', '**Messages lost or unaccounted for:** ' + '; '.join(found) + '.']
    else:
        counted = [c for c in counts if c.published is not None]
        lines += ['', f'Every message published on the {len(counted)} counted streams is in '
                  'the bag (lost 0).']
    if decimated:
        lines.append(f'{decimated} messages were left out by the wall-rate limit '
                     '(`decimated`, plant simulator `max_state_wall_rate_Hz`).')
    lines.append('(`-`: not counted by a node of the run.)')
    return lines
