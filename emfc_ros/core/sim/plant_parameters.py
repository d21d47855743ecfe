"""
The plant_simulator node's parameter table: names, defaults, descriptions, limits, fixed ones.

Plain data, so that the session's configuration (:mod:`emfc_ros.core.sim.plant_config`) and the
node (:mod:`emfc_ros.nodes.plant_simulator`, which declares them) read the same table.
"""

DEFAULT_BALANCE = 'balance_default.yaml'
TIME_MODES = ('owner', 'wall', 'lockstep')
LOCKSTEP_MATCH = ('stamp', 'next')

PARAMETERS = {
    'balance_file': ('', 'balance parameter YAML; empty: the balance.* parameters, or the '
                         'shipped config/balance_default.yaml if there are none'),
    'sample_rate_Hz': (10000.0, 'sample clock of the simulation [Hz]; excitation blocks must '
                                'carry the same rate'),
    'block_size': (1000, 'wall mode: samples simulated per step [samples], 1 to 1000000'),
    'time_mode': ('owner', "'owner': lockstep with the excitation, publishes /clock; 'wall': "
                           "paced to the wall clock; 'lockstep': one controller period "
                           '(sample_rate_Hz / state_rate_Hz samples) per effort command, '
                           'publishes /clock'),
    'seed': (0, 'seed of the sensor and amplifier noise'),
    'noise': (True, 'simulate sensor and amplifier current noise'),
    'quantisation': (True, 'simulate 16-bit DAC and ADC quantisation and saturation'),
    'substeps': (0, 'RK4 steps per sample, 1 to 64; 0: the fewest that resolve the fastest '
                    'mode'),
    'hold': ('zoh', "setpoint hold between samples: 'zoh' or 'foh'"),
    'load_mass_kg': (0.0, 'mass on the pan [kg], 0 to 2; settable at run time'),
    'load_changer_coupled': (False, 'load changer moving mass coupled to the pan; settable at '
                                    'run time'),
    'load_schedule': ('', "mass on the pan over simulated time: 'time_s:mass_kg,...' (e.g. "
                          "'0:0,2:0.0734829,5:0'), each applied at the sample of its time "
                          '(simulated samples since the start) and announced in the '
                          'measurement description; empty: none; fixed at start-up'),
    'state_rate_Hz': (1000.0, 'rate of joint_states [Hz], 0 disables, at most sample_rate_Hz'),
    'command_timeout_s': (0.1, 'effort command watchdog [s]; the command returns to 0 N after '
                               'this long without a new one; lockstep mode: the current state '
                               'is re-published after this long of wall time without an '
                               'answer'),
    'command_delay_periods': (1, 'lockstep mode: 0 = the command answering the state at t_k '
                                 'acts over [t_k, t_k+1) (plus one simulator sample), 1 = one '
                                 'controller period later [periods]'),
    'lockstep_match': ('stamp', "lockstep mode: 'stamp' = a joint_commands message answers the "
                                "state with the same header stamp; 'next' = the next command "
                                'answers the pending state whatever its stamp (ros2_control '
                                'topic-based hardware stamps with its own clock)'),
    'publish_groups': (True, 'also publish measurements/position, current and force'),
    'max_state_wall_rate_Hz': (500.0, 'owner mode: at most this many joint_states per second '
                                      'of wall time [Hz] (evenly chosen from those due at '
                                      'state_rate_Hz of simulated time; the others are counted '
                                      'as states_decimated), so that subscribers keep up when '
                                      'the simulation runs faster than real time; 0: no limit; '
                                      'fixed at start-up'),
    'min_subscribers': (0, 'owner mode: subscribe to the excitation only once this many '
                           'subscriptions to measurements have matched [count], 0 to 100; a '
                           'consumer-paced generator holds sample 0 until then, so a recorder '
                           'started after the plant loses nothing; fixed at start-up'),
    'control.enabled': (False, 'run the position controller inside the sample loop (closed '
                               'loop, docs/closed_loop.md); owner and wall modes only; the '
                               'coil excitation is then added to the controller output'),
    'control.rate_Hz': (10000.0, 'in-loop controller rate [Hz]; sample_rate_Hz must be a '
                                 'whole multiple'),
    'control.crossover_Hz': (130.0, 'design crossover of the in-loop controller [Hz]'),
    'control.phase_margin_deg': (40.0, 'design phase margin [deg]'),
    'control.delay_samples': (1.0, 'controller computation and transport delay [controller '
                                   'samples] (the hold adds half a sample); times the '
                                   'simulator samples per controller sample a whole number '
                                   '>= 1'),
    'control.notch_Hz': (0.0, 'notch centre [Hz]; 0: none (the default: the lever mode, 410 Hz '
                              'empty, 333 Hz with 200 g, stays phase-stabilised at 10 kHz)'),
    'control.max_load_kg': (0.2, 'top of the weighing range [kg]: the design is checked '
                                 '(margins, exact closed-loop poles) at loads from 0 to here and '
                                 'refused if it fails'),
    'control.position_setpoint_m': (0.0, 'lever-end position the loop holds [m]'),
}
CONTROL_PREFIX = 'control.'
#: Inclusive limits of the numeric parameters (descriptors; ``ros2 param describe``).
LIMITS = {'block_size': (1, 1_000_000), 'seed': (0, 2 ** 63 - 1), 'substeps': (0, 64),
          'sample_rate_Hz': (1.0, 10.0e6),
          'load_mass_kg': (0.0, 2.0), 'command_delay_periods': (0, 1),
          'min_subscribers': (0, 100), 'max_state_wall_rate_Hz': (0.0, 1.0e6)}
#: Parameters fixed at start-up (``state_rate_Hz`` too in lockstep mode: refused then).
READ_ONLY = ('sample_rate_Hz', 'block_size', 'time_mode', 'seed', 'noise', 'quantisation',
             'substeps', 'hold', 'publish_groups', 'command_delay_periods', 'lockstep_match',
             'min_subscribers', 'max_state_wall_rate_Hz', 'load_schedule') + \
    tuple(n for n in PARAMETERS if n.startswith(CONTROL_PREFIX))
#: Shown in the start-up log line (with every parameter set to a non-default value).
STARTUP_KEYS = ('time_mode', 'sample_rate_Hz', 'load_mass_kg', 'balance_file',
                'control.enabled')
HELP_EXTRA = ('balance.*: balance parameters (the keys of config/balance_default.yaml, '
              'flattened), used when balance_file is empty; settable at run time.')
