"""
The simulated balance as a weighing instrument.

What ``emfc-weigh`` composes in one process, as three processes in one namespace: the plant
simulator with its in-loop controller, owning time (it simulates the excitation it receives
and publishes the clock), a signal generator paced by the wall clock that sends it an hour of
zero excitation (``config/weighing_hold.yaml``: real time), and the weighing node. The plant
waits for ``min_subscribers`` (default 1: the weighing node) listeners of its measurements,
the generator for the plant (``excitation/ready``), so the sample clock starts when the
weighing node listens. ``load`` puts masses on the pan at times of the sample clock
(``time_s:mass_kg,...``); the plant's measurement description announces each change at its
sample. Zero with ``ros2 service call /emfc/weighing/zero std_srvs/srv/Trigger`` once a
reading of the empty pan is steady (before the first mass goes on: 20 s in the line below)
and watch ``ros2 topic echo /emfc/weighing/reading`` (``docs/weighing.md``, section 8).

    ros2 launch emfc_ros weigh.launch.py load:=0:0,20:0.0734829

Every launch file takes ``namespace:=`` (default ``emfc``) and ``discovery_range:=`` (the
nodes' ``ROS_AUTOMATIC_DISCOVERY_RANGE``; default ``LOCALHOST``); ``clock_topic:=clock``
gives the instance its own clock (two simulated balances on one domain). An argument the
file does not declare is an error (``--show-args`` lists them).
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
    """Describe the plant simulator in closed loop, its excitation and the weighing node."""
    share = FindPackageShare('emfc_ros')
    env = node_environment()
    balance = LaunchConfiguration('balance_file')
    namespace = LaunchConfiguration('namespace')
    clock = [('/clock', LaunchConfiguration('clock_topic'))]
    arguments = [
        DeclareLaunchArgument(
            'balance_file',
            default_value=PathJoinSubstitution([share, 'config', 'balance_default.yaml']),
            description='balance parameter YAML of the simulated balance and the weighing'),
        DeclareLaunchArgument('load', default_value='',
                              description="masses on the pan: 'time_s:mass_kg,...' on the "
                                          'sample clock (e.g. 0:0,20:0.0734829); empty: none'),
        DeclareLaunchArgument('seed', default_value='0',
                              description='seed of the simulated noise'),
        DeclareLaunchArgument('min_subscribers', default_value='1',
                              description='the plant starts once this many subscriptions to '
                                          'measurements matched (1: the weighing node) '
                                          '[count]; 0: at once'),
        DeclareLaunchArgument('clock_topic', default_value='/clock',
                              description='topic of the simulated time the plant publishes; '
                                          'clock (relative) puts it in the namespace'),
        *common_arguments(),
    ]
    return LaunchDescription([
        refuse_undeclared(declared_names(arguments)),
        *arguments,
        Node(
            package='emfc_ros', executable='plant_simulator', name='plant_simulator',
            namespace=namespace, output='screen', additional_env=env, remappings=clock,
            parameters=[{
                'balance_file': balance,
                'time_mode': 'owner',
                'control.enabled': True,
                'load_schedule': ParameterValue(LaunchConfiguration('load'), value_type=str),
                'seed': ParameterValue(LaunchConfiguration('seed'), value_type=int),
                'min_subscribers': ParameterValue(LaunchConfiguration('min_subscribers'),
                                                  value_type=int),
                'state_rate_Hz': 0.0,
            }],
        ),
        Node(
            package='emfc_ros', executable='signal_generator', name='signal_generator',
            namespace=namespace, output='screen', additional_env=env, remappings=clock,
            parameters=[{
                'experiment_file': PathJoinSubstitution([share, 'config',
                                                         'weighing_hold.yaml']),
                'pacing': 'wall',
                # sample 0 waits for the plant: the start is simulated too
                'start_gate': 'applier',
            }],
        ),
        Node(
            package='emfc_ros', executable='weighing', name='weighing',
            namespace=namespace, output='screen', additional_env=env, remappings=clock,
            parameters=[{'balance_file': balance}],
        ),
    ])
