"""
Excitation signals and experiments for EMFC balance identification (no ROS imports).

Every signal has ``sample_rate_Hz`` and ``samples(k)``, a pure function of the int64 local
sample indices ``k``, so generating in blocks of any size gives identical results. An
:class:`Experiment` sequences named sections that drive the setpoint channels.
"""

from emfc_ros.core.signals.base import Signal
from emfc_ros.core.signals.chirp import Chirp
from emfc_ros.core.signals.experiment import (ChannelLimits, ChannelPlan, DEFAULT_CHANNELS,
                                              Experiment, Section)
from emfc_ros.core.signals.multisine import Multisine, select_lines
from emfc_ros.core.signals.noise import GaussianNoise, UniformNoise
from emfc_ros.core.signals.prbs import Prbs
from emfc_ros.core.signals.sine import Sine
from emfc_ros.core.signals.spec import (experiment_from_config, find_experiment_mapping,
                                        load_experiment_file, signal_from_config)
from emfc_ros.core.signals.steps import Constant, staircase, Steps
from emfc_ros.core.signals.waveform import load_waveform, Waveform

__all__ = [
    'ChannelLimits', 'ChannelPlan', 'Chirp', 'Constant', 'DEFAULT_CHANNELS', 'Experiment',
    'GaussianNoise', 'Multisine', 'Prbs', 'Section', 'Signal', 'Sine', 'Steps',
    'UniformNoise', 'Waveform', 'experiment_from_config', 'find_experiment_mapping',
    'load_experiment_file', 'load_waveform', 'select_lines', 'signal_from_config',
    'staircase',
]
