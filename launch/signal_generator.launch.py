"""
Launch the signal generator in namespace ``emfc`` (needs a full ROS 2 Jazzy install).

Arguments: ``experiment_file`` (YAML; default the shipped identification trajectory),
``pacing`` (``wall`` or ``consumer``), ``block_size`` (samples per block).

    ros2 launch emfc_ros signal_generator.launch.py pacing:=wall
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare


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
            additional_env={'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'},
        ),
    ])
