"""
Replay the measurements of a recorded bag through the daq_bridge (needs a full ROS install).

The bridge's ``replay`` back-end re-publishes the bag's ``*/measurements`` blocks with their
recorded sample indices, paced by the original receive times (``pacing:=sample_clock`` paces
by the sample clock, ``pacing:=fast`` as fast as possible), so that identifiers, controllers
and plots can be run again on recorded data.

    ros2 launch emfc_ros replay.launch.py bag:=out/identification-.../bag pacing:=receive_time
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue


def generate_launch_description():
    """Describe the daq_bridge with the replay back-end in namespace emfc."""
    env = {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    return LaunchDescription([
        DeclareLaunchArgument('bag', description='the recorded bag folder'),
        DeclareLaunchArgument('topic', default_value='',
                              description="block topic; empty: the bag's */measurements"),
        DeclareLaunchArgument('pacing', default_value='receive_time',
                              description="'receive_time', 'sample_clock' or 'fast'"),
        DeclareLaunchArgument('speed', default_value='1.0', description='speed factor'),
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
            }],
        ),
    ])
