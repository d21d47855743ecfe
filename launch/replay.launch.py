"""
Replay the measurements of a recorded bag through the daq_bridge.

The bridge's ``replay`` back-end re-publishes the bag's ``*/measurements`` blocks with their
recorded sample indices, paced by the original receive times (``pacing:=sample_clock`` paces
by the sample clock, ``pacing:=fast`` as fast as possible), so that identifiers, controllers
and plots can be run again on recorded data. The replay starts once ``min_subscribers``
(default 1) subscriptions to ``measurements`` matched, so that the listener (a recorder, the
identifier) gets the bag from its first block whichever was started first;
``min_subscribers:=0`` starts at once. When the last block is out, the bridge's ``~/status``
says ``state: done`` (``replay.loop:=true`` starts over instead).

    ros2 launch emfc_ros replay.launch.py bag:=out/identification-.../bag pacing:=receive_time

Every launch file takes ``namespace:=`` (default ``emfc``) and ``discovery_range:=`` (the
nodes' ``ROS_AUTOMATIC_DISCOVERY_RANGE``; default ``LOCALHOST``, discovery on this computer
only); ``ROS_STATIC_PEERS`` set in the shell reaches the nodes as it is
(docs/two_computers.md). An argument the file does not declare is an error (``--show-args``
lists them).
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

from emfc_ros.launch_support import (common_arguments, declared_names, node_environment,
                                     refuse_undeclared)


def generate_launch_description():
    """Describe the daq_bridge with the replay back-end in one namespace."""
    arguments = [
        DeclareLaunchArgument('bag', description='the recorded bag folder'),
        DeclareLaunchArgument('topic', default_value='',
                              description="block topic; empty: the bag's */measurements"),
        DeclareLaunchArgument('pacing', default_value='receive_time',
                              choices=['receive_time', 'sample_clock', 'fast'],
                              description='receive_time = the original block timing, '
                                          'sample_clock = the sample clock, fast = at once'),
        DeclareLaunchArgument('speed', default_value='1.0', description='speed factor'),
        DeclareLaunchArgument('loop', default_value='false', choices=['true', 'false'],
                              description='start over in a new epoch after the last block'),
        DeclareLaunchArgument('min_subscribers', default_value='1',
                              description='the replay starts once this many subscriptions to '
                                          'measurements matched; 0: at once'),
        *common_arguments(),
    ]
    return LaunchDescription([
        refuse_undeclared(declared_names(arguments)),
        *arguments,
        Node(
            package='emfc_ros', executable='daq_bridge', name='daq_bridge',
            namespace=LaunchConfiguration('namespace'), output='screen',
            additional_env=node_environment(),
            parameters=[{
                'backend': 'replay',
                'replay.bag': LaunchConfiguration('bag'),
                'replay.topic': LaunchConfiguration('topic'),
                'replay.pacing': LaunchConfiguration('pacing'),
                'replay.speed': ParameterValue(LaunchConfiguration('speed'),
                                               value_type=float),
                'replay.loop': ParameterValue(LaunchConfiguration('loop'), value_type=bool),
                'min_subscribers': ParameterValue(LaunchConfiguration('min_subscribers'),
                                                  value_type=int),
            }],
        ),
    ])
