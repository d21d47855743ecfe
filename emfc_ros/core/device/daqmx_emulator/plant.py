"""
The simulated balance on the emulated device's terminals, wired as ``docs/daqmx.md`` shows.

The analog outputs drive the balance's amplifier inputs (:data:`DEFAULT_AO_WIRING`); each
analog input carries one simulated signal as the signal conditioning presents it (``volts =
value / units_per_V``, :data:`DEFAULT_AI_WIRING`). Terminals with nothing connected read 0 V.
"""

from __future__ import annotations

from typing import Any, Dict, Mapping, Optional, Sequence

import numpy as np

from emfc_ros.core.device.daqmx_wiring import AiWire, DEFAULT_AI_WIRING, DEFAULT_AO_WIRING
from emfc_ros.core.model.balance_file import load_balance


class BalancePlant:
    """
    The simulated balance behind the terminals (:class:`~.model.Plant`).

    Parameters
    ----------
    params : BalanceParameters, optional
        The balance; the shipped defaults when None.
    seed : int
        Noise seed (every start restarts the balance with it).
    ai_wiring : sequence of AiWire
        What each analog input measures.
    ao_terminals : sequence of str
        The device's analog outputs in order (``('ao0', 'ao1')``).
    simulator_options : mapping, optional
        Keyword arguments of :class:`~emfc_ros.core.sim.simulator.Simulator` (``noise``,
        ``load_mass_kg``, ``load_changer_coupled``).
    """

    def __init__(self, params: Any = None, seed: int = 0,
                 ai_wiring: Sequence[AiWire] = DEFAULT_AI_WIRING,
                 ao_terminals: Sequence[str] = ('ao0', 'ao1'),
                 simulator_options: Optional[Mapping[str, Any]] = None) -> None:
        self.params = load_balance() if params is None else params
        self.seed = int(seed)
        self.ai_wiring = tuple(ai_wiring)
        self.options = dict(simulator_options or {})
        terminals = list(ao_terminals)
        #: The device output row of the coil and the load-changer setpoint.
        self.ao_rows = [terminals.index(term) for _, term in DEFAULT_AO_WIRING]
        self.sim: Any = None
        self._rows: Dict[str, int] = {}
        self.samples = 0
        # build one now: the first build loads the compiled kernels (about a second), which
        # would otherwise stall the device's first start
        self.start(10000.0)
        self.step(np.zeros((len(terminals), 1)))
        self.sim = None

    def start(self, sample_rate_Hz: float) -> None:
        """
        Restart the balance at rest for a new acquisition.

        Parameters
        ----------
        sample_rate_Hz : float
            The AI sample clock [Hz].
        """
        from emfc_ros.core.sim.simulator import Simulator
        self.sim = Simulator(self.params, float(sample_rate_Hz), self.seed, **self.options)
        names = list(self.sim.channel_names)
        self._rows = {w.terminal: names.index(w.name) for w in self.ai_wiring
                      if w.name in names}
        self.samples = 0

    def step(self, ao_V: np.ndarray) -> Dict[str, np.ndarray]:
        """
        The balance driven by the outputs for ``n`` ticks.

        Parameters
        ----------
        ao_V : numpy.ndarray
            Output volts ``(n_ao, n)`` in device order.

        Returns
        -------
        dict
            Analog input terminal to volts ``(n,)``.
        """
        if self.sim is None:
            return {}
        values = self.sim.step_block(np.ascontiguousarray(ao_V[self.ao_rows]))
        self.samples += ao_V.shape[1]
        return {w.terminal: values[self._rows[w.terminal]] / w.units_per_V
                for w in self.ai_wiring if w.terminal in self._rows}
