"""The node's subscriptions for `pose_source: slam_toolbox_graph` (slam_toolbox's pose-graph
interface, pull request 818; docs/slam_bridges.md).

slam_toolbox's own generated message classes are needed to subscribe: they come with the ROS 2
package `slam_toolbox` of a release that has the interface, and from no pip package. Without
them the node cannot take this input at all, so it ends at start-up (MissingInterfaces: one
line on stderr, exit code 2) instead of running blind.

Topics, relative and remappable, named as slam_toolbox's node publishes them in its namespace:
`slam_toolbox/new_node_event`, `slam_toolbox/loop_closure_event` (both reliable, volatile,
depth 10 on slam_toolbox's side) and `slam_toolbox/pose_graph` (reliable, transient local,
depth 1: a node started late still gets the newest graph). The graph is read from its bytes
(io/messages.py): a message object per node and edge would hold the interpreter for
milliseconds per hundred nodes.
"""
from __future__ import annotations

import time
from collections.abc import Callable

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from map_consistency_ros.core.live import LoopClosure, NodeEvent, PoseGraphNodes
from map_consistency_ros.io.messages import (LOOP_CLOSURE_EVENT_TYPE, NEW_NODE_EVENT_TYPE,
                                             POSE_GRAPH_TYPE, SLAM_TOOLBOX_GRAPH_TYPES)
from map_consistency_ros.ros.conversions import message_class

TOPICS = {NEW_NODE_EVENT_TYPE: 'slam_toolbox/new_node_event',
          LOOP_CLOSURE_EVENT_TYPE: 'slam_toolbox/loop_closure_event',
          POSE_GRAPH_TYPE: 'slam_toolbox/pose_graph'}
# the topic each record came from, for the node's input-problem reports
RECORD_TOPICS = {NodeEvent: TOPICS[NEW_NODE_EVENT_TYPE],
                 LoopClosure: TOPICS[LOOP_CLOSURE_EVENT_TYPE],
                 PoseGraphNodes: TOPICS[POSE_GRAPH_TYPE]}
# Every node event names a scan, and one lost is a scan never judged: deep, so that the node
# takes them all while it is busy (slam_toolbox keeps only 10 unacknowledged ones).
EVENTS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.VOLATILE, history=HistoryPolicy.KEEP_LAST)
# Each graph replaces the previous one: the newest is enough, transient local like slam_toolbox's
# publisher so that a node started after the last loop closure gets it.
GRAPHS = QoSProfile(depth=2, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.TRANSIENT_LOCAL, history=HistoryPolicy.KEEP_LAST)

Convert = Callable[[str, str, object], object]  # (topic, type, message or bytes) -> record or None


class MissingInterfaces(Exception):
    """slam_toolbox's message classes cannot be imported."""


def require_interfaces() -> None:
    """MissingInterfaces unless slam_toolbox's pose-graph message classes import."""
    try:
        for msgtype in SLAM_TOOLBOX_GRAPH_TYPES:
            message_class(msgtype)
    except (ImportError, AttributeError) as error:
        # Pull request 818 went to slam_toolbox's ros2 branch only: no Jazzy release (2.8.x)
        # lists it, so on Jazzy it most likely means building slam_toolbox from that branch.
        raise MissingInterfaces(
            'pose_source slam_toolbox_graph needs the ROS 2 package slam_toolbox with its '
            'pose-graph messages (slam_toolbox/msg/PoseGraph, NewNodeEvent, LoopClosureEvent: '
            f'pull request 818), which cannot be imported here ({error}); '
            '`ros2 interface show slam_toolbox/msg/PoseGraph` tells whether the installed '
            "slam_toolbox has them: Jazzy's releases (2.8.x) most likely do not (build "
            "slam_toolbox from its ros2 branch); without them use pose_source slam_toolbox "
            '(its pose and graph markers)') from None


def _subscribe(node, msgtype: str, callback, qos: QoSProfile, group, raw: bool = False) -> None:
    node.create_subscription(message_class(msgtype), TOPICS[msgtype], callback, qos,
                             callback_group=group, raw=raw)


def subscribe(node, group, convert: Convert, convert_bytes: Convert,
              queue: Callable[[float, object], None]) -> None:
    """Subscribe `node` to the three topics: each message becomes a record handed to `queue`
    in arrival order, with its arrival.

    Parameters
    ----------
    node: the node that subscribes.
    group: the callback group of the three subscriptions.
    convert: convert(topic, type, message) of a node or loop-closure event: its record,
        None when it was bad (`convert` counts the problem).
    convert_bytes: the same for the pose graph, taken raw: its serialized bytes.
    queue: queue(arrival, record) takes each record (None for a bad message) and the
        time.monotonic at which its callback began, before the conversion.

    MissingInterfaces when slam_toolbox's message classes cannot be imported.
    """
    require_interfaces()
    # arguments are evaluated left to right: the arrival is taken before the conversion
    for msgtype in (NEW_NODE_EVENT_TYPE, LOOP_CLOSURE_EVENT_TYPE):
        _subscribe(node, msgtype,
                   lambda msg, kind=msgtype: queue(time.monotonic(),
                                                   convert(TOPICS[kind], kind, msg)),
                   EVENTS, group)
    _subscribe(node, POSE_GRAPH_TYPE,
               lambda data: queue(time.monotonic(), convert_bytes(TOPICS[POSE_GRAPH_TYPE],
                                                                  POSE_GRAPH_TYPE, data)),
               GRAPHS, group, raw=True)
