"""
Launch the signal generator in namespace ``emfc`` (needs a full ROS 2 Jazzy install).

Arguments: ``experiment_file`` (YAML; default the shipped identification trajectory),
``pacing`` (``wall`` or ``consumer``), ``block_size`` (samples per block),
``discovery_range`` (the node's ``ROS_AUTOMATIC_DISCOVERY_RANGE``, default ``LOCALHOST``).

    ros2 launch emfc_ros signal_generator.launch.py pacing:=wall
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
    """Describe the signal_generator node with its launch arguments."""
    default_experiment = PathJoinSubstitution(
        [FindPackageShare('emfc_ros'), 'config', 'identification_trajectory.yaml'])
    return LaunchDescription([
        DeclareLaunchArgument('experiment_file', default_value=default_experiment,
                              description='experiment YAML file'),
        DeclareLaunchArgument('pacing', default_value='wall',
                              description="'wall' or 'consumer'"),
        DeclareLaunchArgument('block_size', default_value='1000',
                              description='samples per excitation block'),
        DeclareLaunchArgument(
            'discovery_range', default_value='LOCALHOST', choices=DISCOVERY_RANGES,
            description='ROS_AUTOMATIC_DISCOVERY_RANGE of the nodes: LOCALHOST keeps '
                        'discovery on this computer (ROS_STATIC_PEERS in the environment '
                        'adds named computers: README, Two computers); SUBNET multicasts '
                        'it on every network this computer is on'),
        Node(
            package='emfc_ros',
            executable='signal_generator',
            name='signal_generator',
            namespace='emfc',
            output='screen',
            parameters=[{
                'experiment_file': LaunchConfiguration('experiment_file'),
                'pacing': LaunchConfiguration('pacing'),
                'block_size': ParameterValue(LaunchConfiguration('block_size'), value_type=int),
            }],
            additional_env={'ROS_AUTOMATIC_DISCOVERY_RANGE':
                            LaunchConfiguration('discovery_range')},
        ),
    ])
