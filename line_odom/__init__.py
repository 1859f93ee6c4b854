"""line_odom: connects the line_odom_core engine to the world (ROS 2 node, messages, datasets, bags, evaluation)."""
from line_odom_core import __version__

__all__ = ["__version__"]
