"""The I/O layer's error, importable without the bag libraries (the CLI catches it)."""


class BagError(Exception):
    """A bag cannot be read as the contract's (unreadable or damaged file, not rosbag2,
    missing topic, malformed message); the message names the file, topic and field."""
