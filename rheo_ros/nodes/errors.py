"""The node layer's error, importable without rclpy (the CLI catches it)."""


class GraphError(Exception):
    """The ROS graph is not as a tool needs it (a topic or a subscriber missing after a
    timeout); the message names the topic."""
