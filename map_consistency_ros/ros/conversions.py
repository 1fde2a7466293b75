"""rclpy's message classes for the ROS-free builders and readers of io/messages.py.

The conversion itself lives in io/messages.py, shared with bag replay; this only names the
classes, importing their packages on first use (`--publish` and tests need no node).
"""
from __future__ import annotations

import importlib
from functools import cache


@cache
def message_class(msgtype: str) -> type:
    """The rclpy message class of a message type (this function is the messages.MessageTypes
    that the builders of io/messages.py take).

    Parameters
    ----------
    msgtype: 'pkg/msg/Name', e.g. 'sensor_msgs/msg/LaserScan'.

    Returns
    -------
    The class, its package imported on the first call; ImportError when the package is not
    installed, AttributeError when it has no such message.
    """
    package, kind, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{package}.{kind}'), name)
