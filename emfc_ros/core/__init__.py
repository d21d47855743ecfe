"""
The numerical core of emfc_ros.

Nothing below this package imports rclpy or a ROS message package; a test enforces it.
Time is injected by callers, never read here.
"""
