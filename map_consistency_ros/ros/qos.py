"""The QoS profiles of the node's topics (docs/node.md, Inputs and Outputs)."""
from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

# the latest value for a subscriber that joins late: the verdict, the report, a retune's result
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     history=HistoryPolicy.KEEP_LAST)
RELIABLE = QoSProfile(depth=2, reliability=ReliabilityPolicy.RELIABLE,
                      history=HistoryPolicy.KEEP_LAST)
SINGLE_POSES = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE,
                          history=HistoryPolicy.KEEP_LAST)
# slam_toolbox publishes its graph markers reliable with depth 1; every snapshot counts (the
# bridge chains its headings from one to the next), so keep a few while the node is busy.
GRAPH = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                   history=HistoryPolicy.KEEP_LAST)


def scan_qos(depth: int, reliable: bool) -> QoSProfile:
    """The scan subscription's profile.

    Parameters
    ----------
    depth: messages kept (NodeSettings.scan_queue_depth).
    reliable: RELIABLE; False: BEST_EFFORT, as many drivers publish their scans
        (NodeSettings.scan_reliability).

    Returns
    -------
    A volatile keep-last profile.
    """
    return QoSProfile(depth=depth, reliability=(ReliabilityPolicy.RELIABLE if reliable
                                                else ReliabilityPolicy.BEST_EFFORT),
                      durability=DurabilityPolicy.VOLATILE, history=HistoryPolicy.KEEP_LAST)
