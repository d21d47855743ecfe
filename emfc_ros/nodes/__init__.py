"""Thin rclpy nodes; message conversions live in :mod:`emfc_ros.nodes.convert`."""
