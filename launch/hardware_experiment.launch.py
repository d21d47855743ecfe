"""
An experiment on the balance hardware (or the device emulator); needs a full ROS 2 Jazzy install.

The signal generator, paced by the wall clock, streams the excitation to the daq_bridge, which
writes it to the device over UDP ``excitation_lead_s`` ahead of the device's sample clock and
publishes the measured blocks with the device's sample indices. The bridge starts the device
and subscribes to the excitation once ``min_subscribers`` (default 1) subscriptions to
``/emfc/measurements`` matched, and the generator holds sample 0 until the bridge's
subscription matched, so that the recording (started before or after the launch) has the
experiment from its first sample. Record with
``ros2 bag record -s mcap /emfc/excitation /emfc/excitation/description /emfc/measurements
/emfc/measurements/description /diagnostics``.

    emfc-device-emulator --port 5555 &          # or the real device
    ros2 launch emfc_ros hardware_experiment.launch.py device_port:=5555

Every launch file takes ``discovery_range:=`` (the nodes' ``ROS_AUTOMATIC_DISCOVERY_RANGE``;
default ``LOCALHOST``, discovery on this computer only); ``ROS_STATIC_PEERS`` set in the
shell reaches the nodes as it is (README, Two computers).
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare


#: Values of ROS_AUTOMATIC_DISCOVERY_RANGE (rcl).
DISCOVERY_RANGES = ['LOCALHOST', 'SUBNET', 'OFF', 'SYSTEM_DEFAULT']


def generate_launch_description():
    """Describe the wall-paced signal generator and the udp daq_bridge in namespace emfc."""
    share = FindPackageShare('emfc_ros')
    env = {'ROS_AUTOMATIC_DISCOVERY_RANGE': LaunchConfiguration('discovery_range')}
    return LaunchDescription([
        DeclareLaunchArgument(
            'experiment_file',
            default_value=PathJoinSubstitution([share, 'config',
                                                'identification_trajectory.yaml'])),
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
        DeclareLaunchArgument('min_subscribers', default_value='1',
                              description='the device starts once this many subscriptions to '
                                          '/emfc/measurements (a recorder) matched; 0: at once'),
        DeclareLaunchArgument(
            'discovery_range', default_value='LOCALHOST', choices=DISCOVERY_RANGES,
            description='ROS_AUTOMATIC_DISCOVERY_RANGE of the nodes: LOCALHOST keeps '
                        'discovery on this computer (ROS_STATIC_PEERS in the environment '
                        'adds named computers: README, Two computers); SUBNET multicasts '
                        'it on every network this computer is on'),
        Node(
            package='emfc_ros', executable='daq_bridge', name='daq_bridge',
            namespace='emfc', output='screen', additional_env=env,
            parameters=[LaunchConfiguration('bridge_params_file'), {
                'backend': 'udp',
                'udp.device_host': LaunchConfiguration('device_host'),
                'udp.device_port': ParameterValue(LaunchConfiguration('device_port'),
                                                  value_type=int),
                'excitation_mode': 'stream',
                'min_subscribers': ParameterValue(LaunchConfiguration('min_subscribers'),
                                                  value_type=int),
            }],
        ),
        Node(
            package='emfc_ros', executable='signal_generator', name='signal_generator',
            namespace='emfc', output='screen', additional_env=env,
            parameters=[{
                'experiment_file': LaunchConfiguration('experiment_file'),
                'pacing': 'wall',
                # Sample 0 waits for the bridge's subscription: the excitation sent before
                # discovery matched would be lost (the start of the experiment never applied).
                'min_subscribers': 1,
                'block_size': ParameterValue(LaunchConfiguration('block_size'),
                                             value_type=int),
            }],
        ),
    ])
