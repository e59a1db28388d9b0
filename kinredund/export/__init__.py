"""Export of trajectory records in the forms robot controllers and tools read, and readers for each.

- :mod:`~kinredund.export.samples`: :class:`JointSamples` (joint names, t, q, qdot, qddot), the common
  content of every format, and :class:`ExportError`;
- :mod:`~kinredund.export.csv_file`: CSV, one row per sample, a header naming the joints;
- :mod:`~kinredund.export.rosbag`: a ROS 2 bag holding one ``trajectory_msgs/msg/JointTrajectory``.

The strict JSON record is the trajectory's own (:meth:`kinredund.trajectory.Trajectory.save_json`).
"""

from kinredund.export.csv_file import read_csv, write_csv
from kinredund.export.rosbag import DEFAULT_TOPIC, read_bag, write_bag
from kinredund.export.samples import ExportError, JointSamples

__all__ = ["DEFAULT_TOPIC", "ExportError", "JointSamples", "read_bag", "read_csv", "write_bag", "write_csv"]
