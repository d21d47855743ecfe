"""
The daq_bridge's parameters: names, defaults, descriptions, limits and which are fixed.

The back-ends' own (``sim.*``, ``udp.*``, ``replay.*``, ``daqmx.*``) come from the back-end
registry (:mod:`emfc_ros.core.device.registry`), the function-generator fields from
:mod:`emfc_ros.core.device.bridge_settings`; ``docs/parameters.md`` lists them all (generated
by :mod:`emfc_ros.nodes.param_reference`), ``docs/daq_bridge.md`` explains them.
"""

from __future__ import annotations

from typing import Any, Dict, Tuple

from rclpy.parameter import Parameter

from emfc_ros.core.device import registry
from emfc_ros.core.device.backend import DEFAULT_INPUTS, DEFAULT_OUTPUTS
from emfc_ros.core.device.bridge_settings import FUNCGEN_FIELDS, funcgen_key, RUNTIME

__all__ = ['FUNCGEN_FIELDS', 'FUNCGEN_LIMITS', 'LIMITS', 'PARAMETER_GROUPS', 'PARAMETERS',
           'READ_ONLY', 'RUNTIME', 'STARTUP_KEYS', 'funcgen_key', 'funcgen_limits',
           'funcgen_table']

#: Parameters whose type is declared without a default (empty: derived).
_UNSET_STRINGS = Parameter.Type.STRING_ARRAY
_UNSET_DOUBLES = Parameter.Type.DOUBLE_ARRAY

PARAMETERS: Dict[str, Tuple[Any, str]] = {
    'backend': ('sim', registry.backend_summary()),
    'autostart': (True, 'configure and start the device when the node comes up'),
    'min_subscribers': (0, 'autostart: start the device (or the replay) and subscribe to the '
                           'excitation only once this many subscriptions to measurements have '
                           'matched [count], so that a listener started with the node loses '
                           'nothing'),
    'sample_rate_Hz': (10000.0, 'device sample clock [Hz], (0, 1e7]'),
    'block_size': (1000, 'samples per channel per measurement block [samples], 1 to 65535'),
    'inputs': (list(DEFAULT_INPUTS), 'measured channel names (the unit is the suffix)'),
    'input_units': (_UNSET_STRINGS, 'SI unit of each input; unset: the converter default'),
    'input_scales': (_UNSET_DOUBLES, 'SI value per converter code of each input [unit/code]; '
                                     'unset: the converter default'),
    'input_offsets': (_UNSET_DOUBLES, 'SI value at code 0 of each input [unit]; unset: 0'),
    'input_noise_rms': (_UNSET_DOUBLES, 'noise at the converter of each input, independent '
                                        'from sample to sample [unit rms], published with the '
                                        'code step in the description (extra.resolution) so '
                                        'that a consumer can budget the quantisation; unset '
                                        'or 0: unknown, no dither assumed'),
    'outputs': (list(DEFAULT_OUTPUTS), 'actuator output names: coil, load changer'),
    'output_min_V': ([-10.0, -10.0], 'lower limit of each output [V]; setpoints are clamped'),
    'output_max_V': ([10.0, 10.0], 'upper limit of each output [V]; setpoints are clamped'),
    'output_safe_V': ([0.0, 0.0], 'safe value of each output [V]: driven when stopped, on '
                                  'watchdog trip and emergency stop'),
    'device_watchdog_timeout_s': (0.5, "the device's own watchdog [s]: outputs safe when the "
                                       'host is silent this long'),
    'excitation_mode': ('stream', "'stream': excitation blocks in; 'function_generator': "
                                  'the on-device generator (funcgen.<output>.*); outputs '
                                  "with waveform 'off' still follow the excitation stream"),
    'excitation_lead_s': (0.1, 'setpoints are written this far ahead of the device clock '
                               '[s], 0 to 10'),
    'watchdog_timeout_s': (1.0, 'outputs go to their safe values when excitation stopped '
                                'arriving for this long [s], (0, 3600]'),
    'state_rate_Hz': (1000.0, 'rate of joint_states [Hz], 0 disables, at most '
                              'sample_rate_Hz'),
    'command_timeout_s': (0.1, 'effort command watchdog [s]: the command returns to 0 N after '
                               'this long without a new one, (0, 60]'),
    'publish_groups': (True, 'also publish measurements/position, current and force'),
    'balance_file': ('', 'balance parameter YAML (motor and amplifier characteristics for '
                         'effort commands, and the sim back-end); empty: the shipped default'),
    'diagnostics_period_s': (1.0, 'period of /diagnostics [s], 0.05 to 60'),
    'publisher_depth': (100, 'history depth of the block publishers [blocks], 1 to 100000: '
                             'a burst after a stall longer than this overruns slow readers'),
    'pan.load_mass_kg': (-1.0, 'mass on the pan during the experiment [kg], 0 to 100, '
                               'published in the measurement description for the '
                               'identification (emfc-identify reads it); negative: not '
                               'declared'),
    'pan.load_changer_coupled': ('', "'true' or 'false': whether the load changer's moving "
                                     'mass rides on the pan (published like '
                                     "pan.load_mass_kg); '': not declared"),
    # every back-end's options: '<backend>.<option>' (core/device/registry.py)
    **registry.parameter_table(),
}


#: Inclusive limits of the numeric parameters (descriptors; ``ros2 param describe``); an
#: open end at 0 is checked by the node.
LIMITS = {'sample_rate_Hz': (0.0, 1e7), 'block_size': (1, 65535),
          'device_watchdog_timeout_s': (0.0, 3600.0), 'excitation_lead_s': (0.0, 10.0),
          'watchdog_timeout_s': (0.0, 3600.0), 'command_timeout_s': (0.0, 60.0),
          'diagnostics_period_s': (0.05, 60.0), 'publisher_depth': (1, 100000),
          'min_subscribers': (0, 100), **registry.parameter_limits()}


def funcgen_table(outputs: Any) -> Dict[str, Tuple[Any, str]]:
    """
    The ``funcgen.<output>.<field>`` parameters of the configured outputs.

    Parameters
    ----------
    outputs : sequence of str
        The output names (the ``outputs`` parameter).

    Returns
    -------
    dict
        Parameter name to (default, description).
    """
    return {f'funcgen.{funcgen_key(str(out))}.{field}': entry for out in outputs or []
            for field, entry in FUNCGEN_FIELDS.items()}


#: Inclusive limits of the generator fields, by field.
FUNCGEN_LIMITS = {'prbs_order': (2, 31)}


def funcgen_limits(table: Dict[str, Tuple[Any, str]]) -> Dict[str, Tuple[int, int]]:
    """
    The limits of the ``funcgen.<output>.<field>`` parameters of a :func:`funcgen_table`.

    Parameters
    ----------
    table : dict
        Parameter name to (default, description), as :func:`funcgen_table` returns.

    Returns
    -------
    dict
        Parameter name to inclusive ``(min, max)``, for the fields that have limits.
    """
    return {name: FUNCGEN_LIMITS[name.rsplit('.', 1)[1]] for name in table
            if name.rsplit('.', 1)[1] in FUNCGEN_LIMITS}


#: Every other parameter of the table is fixed at start-up.
READ_ONLY = tuple(name for name in PARAMETERS if name not in RUNTIME)
#: Shown in the start-up log line (with every parameter set to a non-default value).
STARTUP_KEYS = ('backend', 'excitation_mode', 'sample_rate_Hz', 'block_size', 'autostart')
#: Declared once per output (``--help`` and docs/parameters.md show the fields once).
_FUNCGEN_GROUP = funcgen_table(['<output>'])
PARAMETER_GROUPS = {
    'funcgen.<output>.*': ('the on-device function generator, one group per output '
                           '(<output>: its name without the _V suffix, funcgen.coil.* for '
                           'coil_V); settable at run time', _FUNCGEN_GROUP,
                           funcgen_limits(_FUNCGEN_GROUP)),
}
