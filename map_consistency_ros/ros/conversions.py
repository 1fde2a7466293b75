"""ROS messages <-> numpy at the node's boundary (LaserScan, Path, Float64MultiArray).

Messages -> numpy: the readers of io/bags.py, which read fields by attribute and so serve rclpy
messages as they serve rosbags' (the node and bag replay convert alike); each validates its
message and raises ValueError with a message fit for a log line. numpy -> messages: the
builders below. Nothing here keeps state.
"""
from __future__ import annotations

import math

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
from sensor_msgs.msg import LaserScan
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from map_consistency_ros.core.scan_geometry import SensorModel
from map_consistency_ros.io.bags import (CONSTRAINT_FIELDS, constraints_to_numpy,
                                         path_to_numpy, scan_to_numpy, stamp_to_seconds,
                                         yaw_from_quaternion)

__all__ = ['CONSTRAINT_FIELDS', 'constraints_to_numpy', 'numpy_to_constraints', 'numpy_to_path',
           'numpy_to_scan', 'path_to_numpy', 'scan_to_numpy', 'seconds_to_stamp',
           'stamp_to_seconds', 'yaw_from_quaternion']


def seconds_to_stamp(seconds: float) -> Time:
    """Float seconds as a builtin_interfaces/Time (nanoseconds rounded)."""
    total = round(seconds * 1e9)
    return Time(sec=int(total // 1_000_000_000), nanosec=int(total % 1_000_000_000))


def numpy_to_scan(stamp: float, ranges: np.ndarray, model: SensorModel,
                  frame_id: str = 'laser') -> LaserScan:
    """A LaserScan of ranges (K,) with the beam geometry of `model`."""
    msg = LaserScan()
    msg.header.stamp = seconds_to_stamp(stamp)
    msg.header.frame_id = frame_id
    msg.angle_min = float(model.angle_min)
    msg.angle_increment = float(model.angle_increment)
    msg.angle_max = float(model.angle_min + (len(ranges) - 1) * model.angle_increment)
    msg.range_min = float(model.range_min)
    msg.range_max = float(model.max_range)
    msg.ranges = np.asarray(ranges, dtype=np.float32)
    return msg


def numpy_to_path(stamps: np.ndarray, poses: np.ndarray, frame_id: str,
                  stamp: float | None = None) -> Path:
    """A Path of poses (M, 3) with per-pose stamps (M,) in `frame_id`.

    The header stamp is `stamp`, by default the last pose's.
    """
    msg = Path()
    msg.header.frame_id = frame_id
    if stamp is None:
        stamp = float(stamps[-1]) if len(stamps) else 0.0
    msg.header.stamp = seconds_to_stamp(stamp)
    for seconds, (x, y, yaw) in zip(np.asarray(stamps).tolist(), np.asarray(poses).tolist()):
        entry = PoseStamped()
        entry.header.frame_id = frame_id
        entry.header.stamp = seconds_to_stamp(seconds)
        entry.pose.position.x, entry.pose.position.y = x, y
        entry.pose.orientation.z, entry.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
        msg.poses.append(entry)
    return msg


def numpy_to_constraints(rows: np.ndarray) -> Float64MultiArray:
    """Edge rows (E, 11) with the layout labelled ('edges', 'fields')."""
    rows = np.asarray(rows, dtype=np.float64).reshape(-1, len(CONSTRAINT_FIELDS))
    msg = Float64MultiArray()
    msg.layout.dim = [
        MultiArrayDimension(label='edges', size=rows.shape[0], stride=rows.size),
        MultiArrayDimension(label='fields', size=rows.shape[1], stride=rows.shape[1]),
    ]
    msg.data = rows.ravel().tolist()
    return msg
