"""
Replay the measurements of a recorded bag through the daq_bridge (needs a full ROS install).

The bridge's ``replay`` back-end re-publishes the bag's ``*/measurements`` blocks with their
recorded sample indices, paced by the original receive times (``pacing:=sample_clock`` paces
by the sample clock, ``pacing:=fast`` as fast as possible), so that identifiers, controllers
and plots can be run again on recorded data. The replay starts once ``min_subscribers``
(default 1) subscriptions to ``/emfc/measurements`` matched, so that the listener (a
recorder, the identifier) gets the bag from its first block whichever was started first;
``min_subscribers:=0`` starts at once.

    ros2 launch emfc_ros replay.launch.py bag:=out/identification-.../bag pacing:=receive_time

Every launch file takes ``discovery_range:=`` (the nodes' ``ROS_AUTOMATIC_DISCOVERY_RANGE``;
default ``LOCALHOST``, discovery on this computer only); ``ROS_STATIC_PEERS`` set in the
shell reaches the nodes as it is (README, Two computers).
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue


#: Values of ROS_AUTOMATIC_DISCOVERY_RANGE (rcl).
DISCOVERY_RANGES = ['LOCALHOST', 'SUBNET', 'OFF', 'SYSTEM_DEFAULT']


def generate_launch_description():
    """Describe the daq_bridge with the replay back-end in namespace emfc."""
    env = {'ROS_AUTOMATIC_DISCOVERY_RANGE': LaunchConfiguration('discovery_range')}
    return LaunchDescription([
        DeclareLaunchArgument('bag', description='the recorded bag folder'),
        DeclareLaunchArgument('topic', default_value='',
                              description="block topic; empty: the bag's */measurements"),
        DeclareLaunchArgument('pacing', default_value='receive_time',
                              description="'receive_time', 'sample_clock' or 'fast'"),
        DeclareLaunchArgument('speed', default_value='1.0', description='speed factor'),
        DeclareLaunchArgument('min_subscribers', default_value='1',
                              description='the replay starts once this many subscriptions to '
                                          '/emfc/measurements matched; 0: at once'),
        DeclareLaunchArgument(
            'discovery_range', default_value='LOCALHOST', choices=DISCOVERY_RANGES,
            description='ROS_AUTOMATIC_DISCOVERY_RANGE of the nodes: LOCALHOST keeps '
                        'discovery on this computer (ROS_STATIC_PEERS in the environment '
                        'adds named computers: README, Two computers); SUBNET multicasts '
                        'it on every network this computer is on'),
        Node(
            package='emfc_ros', executable='daq_bridge', name='daq_bridge',
            namespace='emfc', output='screen', additional_env=env,
            parameters=[{
                'backend': 'replay',
                'replay.bag': LaunchConfiguration('bag'),
                'replay.topic': LaunchConfiguration('topic'),
                'replay.pacing': LaunchConfiguration('pacing'),
                'replay.speed': ParameterValue(LaunchConfiguration('speed'),
                                               value_type=float),
                'min_subscribers': ParameterValue(LaunchConfiguration('min_subscribers'),
                                                  value_type=int),
            }],
        ),
    ])
