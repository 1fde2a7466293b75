"""rclpy's message classes for the ROS-free builders and readers of io/messages.py.

The conversion itself lives in io/messages.py, shared with bag replay; this only names the
classes, importing their packages on first use (`--publish` and tests need no node).
"""
from __future__ import annotations

import importlib
from functools import cache


@cache
def message_class(msgtype: str) -> type:
    """The rclpy message class of 'pkg/msg/Name' (a messages.MessageTypes)."""
    package, kind, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{package}.{kind}'), name)
