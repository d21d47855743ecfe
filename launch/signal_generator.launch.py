"""
Launch the signal generator alone.

Arguments: ``experiment_file`` (YAML; default the shipped identification trajectory),
``pacing`` (``wall`` or ``consumer``), ``block_size`` (samples per block), ``start_gate`` and
``min_subscribers`` (what sample 0 waits for: by default one subscription to the excitation,
so that a recorder started before or after the launch gets the experiment from its first
block; ``start_gate:=applier`` waits for a plant simulator or daq_bridge announcing ready on
``excitation/ready``; ``min_subscribers:=0`` streams at once).

    ros2 launch emfc_ros signal_generator.launch.py pacing:=wall

Every launch file takes ``namespace:=`` (default ``emfc``) and ``discovery_range:=`` (the
nodes' ``ROS_AUTOMATIC_DISCOVERY_RANGE``; default ``LOCALHOST``). An argument the file does
not declare is an error (``--show-args`` lists them).
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare

from emfc_ros.launch_support import (common_arguments, declared_names, node_environment,
                                     refuse_undeclared)


def generate_launch_description():
    """Describe the signal_generator node with its launch arguments."""
    default_experiment = PathJoinSubstitution(
        [FindPackageShare('emfc_ros'), 'config', 'identification_trajectory.yaml'])
    arguments = [
        DeclareLaunchArgument('experiment_file', default_value=default_experiment,
                              description='experiment YAML file'),
        DeclareLaunchArgument('pacing', default_value='wall', choices=['wall', 'consumer'],
                              description='wall = the wall clock; consumer = as fast as the '
                                          'consumer acknowledges on excitation/consumed'),
        DeclareLaunchArgument('block_size', default_value='1000',
                              description='samples per excitation block'),
        DeclareLaunchArgument('start_gate', default_value='subscribers',
                              choices=['applier', 'subscribers', 'none'],
                              description='what sample 0 waits for: subscribers = '
                                          'min_subscribers subscriptions to the excitation; '
                                          'applier = a plant_simulator or daq_bridge ready on '
                                          'excitation/ready as well; none = nothing'),
        DeclareLaunchArgument('min_subscribers', default_value='1',
                              description='subscriptions to the excitation sample 0 waits '
                                          'for [count]; 0: none'),
        *common_arguments(),
    ]
    return LaunchDescription([
        refuse_undeclared(declared_names(arguments)),
        *arguments,
        Node(
            package='emfc_ros',
            executable='signal_generator',
            name='signal_generator',
            namespace=LaunchConfiguration('namespace'),
            output='screen',
            parameters=[{
                'experiment_file': LaunchConfiguration('experiment_file'),
                'pacing': ParameterValue(LaunchConfiguration('pacing'), value_type=str),
                'block_size': ParameterValue(LaunchConfiguration('block_size'), value_type=int),
                'start_gate': ParameterValue(LaunchConfiguration('start_gate'),
                                             value_type=str),
                'min_subscribers': ParameterValue(LaunchConfiguration('min_subscribers'),
                                                  value_type=int),
            }],
            additional_env=node_environment(),
        ),
    ])
