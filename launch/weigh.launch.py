"""
The simulated balance as a weighing instrument (needs a full ROS 2 Jazzy install).

What ``emfc-weigh`` composes in one process, as three processes in namespace ``emfc``: the
plant simulator with its in-loop controller, owning time (it simulates the excitation it
receives and publishes ``/clock``), a signal generator paced by the wall clock that sends it
an hour of zero excitation (``config/weighing_hold.yaml``: real time), and the weighing
node. ``load`` puts masses on the pan at times of the sample clock (``time_s:mass_kg,...``);
the plant's measurement description announces each change at its sample. Zero with
``ros2 service call /emfc/weighing/zero std_srvs/srv/Trigger`` once a reading is steady, and
watch ``ros2 topic echo /emfc/weighing/reading`` (``docs/weighing.md``, section 8).

    ros2 launch emfc_ros weigh.launch.py load:=0:0,2:0.0734829

Like every launch file it takes ``discovery_range:=`` (the nodes'
``ROS_AUTOMATIC_DISCOVERY_RANGE``; default ``LOCALHOST``).
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
    """Describe the plant simulator in closed loop, its excitation and the weighing node."""
    share = FindPackageShare('emfc_ros')
    env = {'ROS_AUTOMATIC_DISCOVERY_RANGE': LaunchConfiguration('discovery_range')}
    balance = LaunchConfiguration('balance_file')
    return LaunchDescription([
        DeclareLaunchArgument(
            'balance_file',
            default_value=PathJoinSubstitution([share, 'config', 'balance_default.yaml'])),
        DeclareLaunchArgument('load', default_value='',
                              description="masses on the pan: 'time_s:mass_kg,...' on the "
                                          'sample clock (e.g. 0:0,2:0.0734829); empty: none'),
        DeclareLaunchArgument('seed', default_value='0',
                              description='seed of the simulated noise'),
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
                'balance_file': balance,
                'time_mode': 'owner',
                'control.enabled': True,
                'load_schedule': ParameterValue(LaunchConfiguration('load'), value_type=str),
                'seed': ParameterValue(LaunchConfiguration('seed'), value_type=int),
                'state_rate_Hz': 0.0,
            }],
        ),
        Node(
            package='emfc_ros', executable='signal_generator', name='signal_generator',
            namespace='emfc', output='screen', additional_env=env,
            parameters=[{
                'experiment_file': PathJoinSubstitution([share, 'config',
                                                         'weighing_hold.yaml']),
                'pacing': 'wall',
                # sample 0 waits for the plant's subscription: the start is simulated too
                'min_subscribers': 1,
            }],
        ),
        Node(
            package='emfc_ros', executable='weighing', name='weighing',
            namespace='emfc', output='screen', additional_env=env,
            parameters=[{'balance_file': balance}],
        ),
    ])
