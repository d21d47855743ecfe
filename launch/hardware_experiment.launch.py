"""
An experiment on the balance hardware (or the device emulator).

The signal generator streams the excitation to the daq_bridge, which writes it to the device
over UDP ``excitation_lead_s`` ahead of the device's sample clock and publishes the measured
blocks with the device's sample indices. With ``pacing:=consumer`` (the default) the
generator follows the device's clock through the bridge's acknowledgements
(``excitation/consumed``), ``window_blocks`` ahead; ``pacing:=wall`` paces it by this
computer's clock instead, ``lead_blocks`` ahead. The bridge starts the device and subscribes
to the excitation once ``min_subscribers`` (default 1) subscriptions to ``measurements``
matched, then announces itself ready on ``excitation/ready``; the generator holds sample 0
until the bridge is ready and matched and ``excitation_subscribers`` (default 2: the bridge
and a recorder of the excitation) subscriptions to ``excitation`` matched (``start_gate``),
so that the recording, started before or after the launch, has the experiment from its first
sample and the device applies it from sample 0. Record with
``ros2 bag record -s mcap /emfc/excitation /emfc/excitation/description /emfc/measurements
/emfc/measurements/description /diagnostics`` or the recorder line of docs/nodes.md with the same
topics; give the pan load (``load_mass_kg``, ``load_changer_coupled``) so that
``emfc-identify BAG`` finds it in the bag.

emfc-device-emulator --port 5555 --load-mass-kg balance &     # or the real device
ros2 launch emfc_ros hardware_experiment.launch.py load_mass_kg:=0.1274 load_changer_coupled:=false

Every launch file takes ``namespace:=`` (default ``emfc``) and ``discovery_range:=`` (the
nodes' ``ROS_AUTOMATIC_DISCOVERY_RANGE``; default ``LOCALHOST``, discovery on this computer
only); ``ROS_STATIC_PEERS`` set in the shell reaches the nodes as it is
(docs/two_computers.md). An argument the file does not declare is an error (``--show-args``
lists them).
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare

from emfc_ros.launch_support import (common_arguments, declared_names, gate_arguments,
                                     generator_gate_parameters, node_environment,
                                     refuse_undeclared)


def generate_launch_description():
    """Describe the signal generator and the udp daq_bridge in one namespace."""
    share = FindPackageShare('emfc_ros')
    env = node_environment()
    namespace = LaunchConfiguration('namespace')
    arguments = [
        DeclareLaunchArgument(
            'experiment_file',
            default_value=PathJoinSubstitution([share, 'config',
                                                'identification_trajectory.yaml']),
            description="experiment YAML file (default: the paper's identification "
                        'trajectory)'),
        DeclareLaunchArgument(
            'bridge_params_file',
            default_value=PathJoinSubstitution([share, 'config', 'daq_bridge_udp.yaml']),
            description='daq_bridge parameters (ROS params file)'),
        DeclareLaunchArgument('device_host', default_value='127.0.0.1',
                              description='IP address of the device'),
        DeclareLaunchArgument('device_port', default_value='5555',
                              description='UDP port of the device'),
        DeclareLaunchArgument('block_size', default_value='1000',
                              description='samples per excitation block'),
        *gate_arguments('the bridge', 'starts the device', "the device's clock, through the "
                        "bridge's acknowledgements"),
        DeclareLaunchArgument('lead_blocks', default_value='2',
                              description='wall pacing: blocks sent ahead of the wall clock '
                                          '[blocks]'),
        DeclareLaunchArgument('excitation_lead_s', default_value='0.5',
                              description='setpoints are written this far ahead of the '
                                          'device clock [s]; a host stall longer than this '
                                          'underruns the device (a fault); with consumer '
                                          'pacing window_blocks must hold it plus one block'),
        DeclareLaunchArgument('load_mass_kg', default_value='-1.0',
                              description='mass on the pan [kg], published for the '
                                          'identification; negative: not declared'),
        DeclareLaunchArgument('load_changer_coupled', default_value='',
                              description="true or false: whether the load changer's moving "
                                          "mass rides on the pan; '': not declared"),
        *common_arguments(),
    ]
    return LaunchDescription([
        refuse_undeclared(declared_names(arguments)),
        *arguments,
        Node(
            package='emfc_ros', executable='daq_bridge', name='daq_bridge',
            namespace=namespace, output='screen', additional_env=env,
            parameters=[LaunchConfiguration('bridge_params_file'), {
                'backend': 'udp',
                'udp.device_host': LaunchConfiguration('device_host'),
                'udp.device_port': ParameterValue(LaunchConfiguration('device_port'),
                                                  value_type=int),
                'excitation_mode': 'stream',
                'min_subscribers': ParameterValue(LaunchConfiguration('min_subscribers'),
                                                  value_type=int),
                'excitation_lead_s': ParameterValue(LaunchConfiguration('excitation_lead_s'),
                                                    value_type=float),
                'pan.load_mass_kg': ParameterValue(LaunchConfiguration('load_mass_kg'),
                                                   value_type=float),
                'pan.load_changer_coupled': ParameterValue(
                    LaunchConfiguration('load_changer_coupled'), value_type=str),
            }],
        ),
        Node(
            package='emfc_ros', executable='signal_generator', name='signal_generator',
            namespace=namespace, output='screen', additional_env=env,
            parameters=[{
                'experiment_file': LaunchConfiguration('experiment_file'),
                **generator_gate_parameters(),
                'lead_blocks': ParameterValue(LaunchConfiguration('lead_blocks'),
                                              value_type=int),
                'block_size': ParameterValue(LaunchConfiguration('block_size'),
                                             value_type=int),
            }],
        ),
    ])
