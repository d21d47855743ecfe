"""
A load schedule as data: masses put on the pan at samples of the simulation.

Each entry is ``(simulated sample, mass [kg], coupled)`` (``coupled`` None: the load
changer's coupling as it is then). :meth:`LoadSchedule.due` splits a block at the entries
that fall into it, so that the caller simulates up to an entry, applies it, and goes on.
"""

from __future__ import annotations

from typing import Iterable, List, Optional, Tuple

LoadEntry = Tuple[int, float, Optional[bool]]


class LoadSchedule:
    """
    The entries not applied yet, in sample order.

    Parameters
    ----------
    entries : iterable of tuple
        ``(sample, mass_kg, coupled)``; ``sample`` counts simulated samples from the start.
    """

    def __init__(self, entries: Iterable[LoadEntry] = ()) -> None:
        self.pending: List[LoadEntry] = sorted(
            ((int(s), float(m), c) for s, m, c in entries), key=lambda e: e[0])

    def due(self, done: int, n: int) -> List[Tuple[int, List[LoadEntry]]]:
        """
        Take the entries that apply within the next ``n`` samples.

        Parameters
        ----------
        done : int
            Samples simulated so far.
        n : int
            Samples about to be simulated.

        Returns
        -------
        list
            ``(offset, entries)`` pairs, offsets ascending in ``[0, n)``: apply the entries
            before the sample at ``offset`` of the block (an entry already past applies at
            offset 0).
        """
        out: List[Tuple[int, List[LoadEntry]]] = []
        while self.pending and self.pending[0][0] < done + n:
            entry = self.pending.pop(0)
            offset = max(0, entry[0] - done)
            if out and out[-1][0] == offset:
                out[-1][1].append(entry)
            else:
                out.append((offset, [entry]))
        return out
