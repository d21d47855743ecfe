"""
Build script of the emfc_ros ament_python package.

Installs three ways: ``pip install .`` into a virtual environment fed from PyPI,
``colcon build`` (with or without ``--symlink-install``), and a colcon workspace on a full
ROS 2 Jazzy install. ``ros2 run emfc_ros <node>`` finds the small wrapper scripts that
``data_files`` puts in ``<prefix>/lib/emfc_ros``; console scripts get ``emfc-*`` names.
"""

from glob import glob
import os

from setuptools import find_packages, setup

PACKAGE = 'emfc_ros'

# Node executables for `ros2 run emfc_ros <name>`: wrapper scripts in lib_wrappers/.
NODES = {
    'signal_generator': 'emfc_ros.nodes.signal_generator:main',
    'plant_simulator': 'emfc_ros.nodes.plant_simulator:main',
    'position_controller': 'emfc_ros.nodes.position_controller:main',
    'recorder': 'emfc_ros.nodes.recorder:main',
    'identifier': 'emfc_ros.nodes.identifier:main',
    'weighing': 'emfc_ros.nodes.weighing:main',
    'daq_bridge': 'emfc_ros.nodes.daq_bridge:main',
}

# Offline commands for PATH users.
COMMANDS = {
    'emfc-signal-generator': 'emfc_ros.nodes.signal_generator:main',
    'emfc-plant-simulator': 'emfc_ros.nodes.plant_simulator:main',
    'emfc-position-controller': 'emfc_ros.nodes.position_controller:main',
    'emfc-recorder': 'emfc_ros.nodes.recorder:main',
    'emfc-identifier': 'emfc_ros.nodes.identifier:main',
    'emfc-weighing': 'emfc_ros.nodes.weighing:main',
    'emfc-daq-bridge': 'emfc_ros.nodes.daq_bridge:main',
    'emfc-bag-repair': 'emfc_ros.cli.bag_repair:main',
    'emfc-bag-info': 'emfc_ros.cli.bag_info:main',
    'emfc-compile-kernels': 'emfc_ros.cli.compile_kernels:main',
    'emfc-generate': 'emfc_ros.cli.generate:main',
    'emfc-demo': 'emfc_ros.cli.demo:main',
    'emfc-experiment': 'emfc_ros.cli.experiment:console_main',
    'emfc-identify': 'emfc_ros.cli.identify:main',
    'emfc-device-emulator': 'emfc_ros.cli.device_emulator:main',
    'emfc-daqmx-emulator': 'emfc_ros.cli.daqmx_emulator:main',
    'emfc-model-summary': 'emfc_ros.cli.model_summary:main',
    'emfc-simulate': 'emfc_ros.cli.simulate:main',
    'emfc-weigh': 'emfc_ros.cli.weigh:main',
}

# On a full ROS install (ROS_DISTRO set by its setup script) rclpy and the message
# packages come from the distribution, not from PyPI; declaring the PyPI wheels there
# would make setuptools look for distributions that do not exist.
ROS_FROM_PYPI = [] if os.environ.get('ROS_DISTRO') else [
    'ros-jazzy-rclpy[fastrtps]',
    'ros-jazzy-common-interfaces',
]

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*', 'bench', 'bench.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/config', sorted(glob('config/*.yaml'))),
        ('share/' + PACKAGE + '/launch', sorted(glob('launch/*.launch.py'))),
        ('lib/' + PACKAGE, ['lib_wrappers/' + name for name in sorted(NODES)]),
    ],
    python_requires='>=3.10',
    install_requires=[
        'setuptools',
        'numpy>=1.24',
        'scipy>=1.10',
        'PyYAML>=6',
        'rosbags>=0.10',
        'mcap>=1.6',
        'threadpoolctl>=3.1',
        # The compiled kernels (simulator, grey-box fit, closed loop, weighing filter). The
        # code keeps an interpreted fallback for platforms without numba wheels.
        'numba>=0.59',
    ] + ROS_FROM_PYPI,
    extras_require={
        # Kept as an alias for old install lines: numba is a requirement now.
        'fast': ['numba>=0.59'],
        'plot': ['matplotlib>=3.7'],
        # NI-DAQmx devices (issue 24): NI's client, with gRPC for the NI gRPC Device Server
        # and the emulated device; the rest of the package does not need it.
        'daqmx': ['nidaqmx[grpc]>=1.1'],
        # pytest-xdist: tools/test.sh runs the suite in parallel workers
        'test': ['pytest>=7', 'pytest-xdist>=3.5', 'hypothesis>=6', 'mcap>=1.1',
                 'mcap-ros2-support>=0.5'],
    },
    zip_safe=True,
    maintainer='emfc_ros developers',
    maintainer_email='emfc-ros@example.org',
    description='ROS 2 node suite for experiments on EMFC balances',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [f'{name} = {target}' for name, target in sorted(COMMANDS.items())],
    },
)
