"""
emfc_ros: experiments on electromagnetic force compensated balances with ROS 2.

The numerical core lives in :mod:`emfc_ros.core` and never imports ROS; the thin
rclpy nodes live in :mod:`emfc_ros.nodes`; offline commands in :mod:`emfc_ros.cli`.
"""

__version__ = '0.1.0'
