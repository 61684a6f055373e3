"""ROS bags: the `rosbag` importer and writer (registered on import of this package)."""

from importers.rosbag.importer import RosbagImporter

__all__ = ["RosbagImporter"]
