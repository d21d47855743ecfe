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
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare


def generate_launch_description():
    """Describe the wall-paced signal generator and the udp daq_bridge in namespace emfc."""
    share = FindPackageShare('emfc_ros')
    env = {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
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
