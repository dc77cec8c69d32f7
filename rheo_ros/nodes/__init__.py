"""rclpy nodes: thin adapters over the core (messages in, core call, messages out)."""
