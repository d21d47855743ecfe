"""
An experiment on the simulated balance.

The signal generator, consumer-paced, drives the plant simulator, which owns time (it
publishes the clock and runs as fast as the excitation arrives). The two processes, and a
recorder, may come up in any order. The plant subscribes to the excitation once
``min_subscribers`` (default 1) subscriptions to ``measurements`` matched, and then
announces itself ready on ``excitation/ready``. The generator holds sample 0 until the plant
is ready and matched and ``excitation_subscribers`` (default 2: the plant and a recorder of
the excitation) subscriptions to ``excitation`` matched (``start_gate``, docs/nodes.md,
signal_generator). Its status says what it waits for. Record with the recorder line of
docs/nodes.md (``use_sim_time:=true``, ``/clock`` among its topics) or
``ros2 bag record -s mcap --use-sim-time /emfc/excitation /emfc/excitation/description
/emfc/measurements /emfc/measurements/description /clock``.

    ros2 launch emfc_ros sim_experiment.launch.py load_mass_kg:=0.1274

Two simulated balances on one domain: give each its own ``namespace`` and its own clock,
``clock_topic:=clock`` (the relative name puts it in the namespace, ``/a/clock``, and every
node of the instance follows it); a plant that finds another publisher of its clock topic
refuses to simulate and says so (``docs/simulator.md``, Two simulated balances).

    ros2 launch emfc_ros sim_experiment.launch.py namespace:=a clock_topic:=clock

Every launch file takes ``namespace:=`` (default ``emfc``) and ``discovery_range:=`` (the
nodes' ``ROS_AUTOMATIC_DISCOVERY_RANGE``; default ``LOCALHOST``, discovery on this computer
only); ``ROS_STATIC_PEERS`` set in the shell reaches the nodes as it is
(docs/two_computers.md). An argument the file does not declare is an error (``--show-args``
lists them).
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare

from emfc_ros.launch_support import (common_arguments, declared_names, gate_arguments,
                                     generator_gate_parameters, node_environment,
                                     refuse_undeclared)


def generate_launch_description():
    """Describe the signal generator and the plant simulator in one namespace."""
    share = FindPackageShare('emfc_ros')
    env = node_environment()
    namespace = LaunchConfiguration('namespace')
    clock = [('/clock', LaunchConfiguration('clock_topic'))]
    arguments = [
        DeclareLaunchArgument(
            'experiment_file',
            default_value=PathJoinSubstitution([share, 'config',
                                                'identification_trajectory.yaml']),
            description="experiment YAML file (default: the paper's identification "
                        'trajectory)'),
        DeclareLaunchArgument(
            'balance_file',
            default_value=PathJoinSubstitution([share, 'config', 'balance_default.yaml']),
            description='balance parameter YAML of the simulated balance'),
        DeclareLaunchArgument('load_mass_kg', default_value='0.1274',
                              description='mass on the pan [kg]; 0.1274 balances the default '
                                          'lever at zero coil current'),
        DeclareLaunchArgument('seed', default_value='0',
                              description='seed of the simulated noise'),
        *gate_arguments('the plant', 'subscribes to the excitation',
                        "the plant's acknowledgements"),
        DeclareLaunchArgument('clock_topic', default_value='/clock',
                              description='topic of the simulated time the plant publishes '
                                          'and the generator follows; clock (relative) puts '
                                          'it in the namespace, for two simulated balances '
                                          'on one domain'),
        *common_arguments(),
    ]
    return LaunchDescription([
        refuse_undeclared(declared_names(arguments)),
        *arguments,
        Node(
            package='emfc_ros', executable='plant_simulator', name='plant_simulator',
            namespace=namespace, output='screen', additional_env=env, remappings=clock,
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
            namespace=namespace, output='screen', additional_env=env, remappings=clock,
            parameters=[{
                'experiment_file': LaunchConfiguration('experiment_file'),
                **generator_gate_parameters(),
                'use_sim_time': True,
            }],
        ),
    ])
