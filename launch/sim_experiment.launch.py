"""
An experiment on the simulated balance (needs a full ROS 2 Jazzy install).

The signal generator, consumer-paced, drives the plant simulator, which owns time (it
publishes /clock and runs as fast as the excitation arrives). The two processes may come
up in any order: the generator holds sample 0 until the plant's subscription and
acknowledgements are matched and re-sends a window that is not acknowledged (README,
signal_generator). The plant subscribes to the excitation only once ``min_subscribers``
(default 1) subscriptions to ``/emfc/measurements`` are there, so the experiment starts
when a recorder listens (start it after the launch, README): ``ros2 run emfc_ros recorder``
with ``use_sim_time:=true`` and ``/clock`` among its topics (README, plant_simulator) or
``ros2 bag record -s mcap /emfc/excitation /emfc/measurements /clock ...``.

    ros2 launch emfc_ros sim_experiment.launch.py load_mass_kg:=0.1274

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
    """Describe the signal generator and the plant simulator in namespace emfc."""
    share = FindPackageShare('emfc_ros')
    env = {'ROS_AUTOMATIC_DISCOVERY_RANGE': LaunchConfiguration('discovery_range')}
    return LaunchDescription([
        DeclareLaunchArgument(
            'experiment_file',
            default_value=PathJoinSubstitution([share, 'config',
                                                'identification_trajectory.yaml'])),
        DeclareLaunchArgument(
            'balance_file',
            default_value=PathJoinSubstitution([share, 'config', 'balance_default.yaml'])),
        DeclareLaunchArgument('load_mass_kg', default_value='0.1274',
                              description='mass on the pan [kg]; 0.1274 balances the default '
                                          'lever at zero coil current'),
        DeclareLaunchArgument('seed', default_value='0',
                              description='seed of the simulated noise'),
        DeclareLaunchArgument('min_subscribers', default_value='1',
                              description='the experiment starts once this many subscriptions '
                                          'to /emfc/measurements (a recorder) matched; 0: at '
                                          'once'),
        DeclareLaunchArgument(
            'discovery_range', default_value='LOCALHOST', choices=DISCOVERY_RANGES,
            description='ROS_AUTOMATIC_DISCOVERY_RANGE of the nodes: LOCALHOST keeps '
                        'discovery on this computer (ROS_STATIC_PEERS in the environment '
                        'adds named computers: README, Two computers); SUBNET multicasts '
                        'it on every network this computer is on'),
        Node(
            package='emfc_ros', executable='plant_simulator', name='plant_simulator',
            namespace='emfc', output='screen', additional_env=env,
            parameters=[{
                'balance_file': LaunchConfiguration('balance_file'),
                'time_mode': 'owner',
                'load_mass_kg': ParameterValue(LaunchConfiguration('load_mass_kg'),
                                               value_type=float),
                'seed': ParameterValue(LaunchConfiguration('seed'), value_type=int),
                'min_subscribers': ParameterValue(LaunchConfiguration('min_subscribers'),
                                                  value_type=int),
            }],
        ),
        Node(
            package='emfc_ros', executable='signal_generator', name='signal_generator',
            namespace='emfc', output='screen', additional_env=env,
            parameters=[{
                'experiment_file': LaunchConfiguration('experiment_file'),
                'pacing': 'consumer',
                'use_sim_time': True,
            }],
        ),
    ])
