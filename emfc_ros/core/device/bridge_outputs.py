"""
Where a bridge session's outputs go: the :class:`BridgeOutputs` interface.

The daq_bridge node implements it (publishing on its topics, logging); tests record it.
"""

from __future__ import annotations

from typing import Dict, Protocol

import numpy as np

from emfc_ros.core.blocks import Block, StreamDescription


class BridgeOutputs(Protocol):
    """Where a session's outputs go (the node publishes them; a test records them)."""

    def publish_block(self, block: Block) -> None:
        """
        A measurement block, as the device delivered it.

        Parameters
        ----------
        block : Block
            The block, channels in the description's order (SI units).
        """
        ...  # pragma: no cover

    def publish_descriptions(self, descriptions: Dict[str, StreamDescription]) -> None:
        """
        The measurement stream's description and its groups', by relative topic.

        Parameters
        ----------
        descriptions : dict of str to StreamDescription
            Relative topic to the description published on it.
        """
        ...  # pragma: no cover

    def publish_consumed(self, samples: int) -> None:
        """
        Excitation samples the device has applied (cumulative).

        Parameters
        ----------
        samples : int
            Excitation samples applied so far, counted from the stream's first.
        """
        ...  # pragma: no cover

    def publish_states(self, stamps_ns: np.ndarray, position_m: np.ndarray,
                       velocity_m_per_s: np.ndarray, effort_N: np.ndarray) -> None:
        """
        Joint states of the lever: stamps [ns], position [m], velocity [m/s], effort [N].

        Parameters
        ----------
        stamps_ns : numpy.ndarray
            Time stamps [ns], int64, one per state.
        position_m : numpy.ndarray
            Lever-end position [m] (NaN where not measured).
        velocity_m_per_s : numpy.ndarray
            Lever-end velocity [m/s].
        effort_N : numpy.ndarray
            Coil force [N] (NaN where not measured).
        """
        ...  # pragma: no cover

    def status_changed(self) -> None:
        """The state, the error or the readiness may have changed."""
        ...  # pragma: no cover

    def diagnostics_due(self) -> None:
        """Publish the diagnostics now (a fault was latched)."""
        ...  # pragma: no cover

    def open_excitation(self) -> None:
        """Subscribe to the excitation (the wait for listeners ended)."""
        ...  # pragma: no cover

    def log(self, level: str, message: str) -> None:
        """
        A log line: ``level`` one of info, warning, error.

        Parameters
        ----------
        level : str
            ``'info'``, ``'warning'`` or ``'error'``.
        message : str
            The line.
        """
        ...  # pragma: no cover
