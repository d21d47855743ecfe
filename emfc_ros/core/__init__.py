"""
The numerical core of emfc_ros.

Nothing below this package imports rclpy or a ROS message package; a test enforces it.
Time is injected by callers, never read here.
Every error the package raises on purpose subclasses :class:`EmfcError` (and a builtin).
"""

from emfc_ros.core.errors import EmfcError

__all__ = ['EmfcError']
