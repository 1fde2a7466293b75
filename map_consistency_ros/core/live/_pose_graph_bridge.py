"""slam_toolbox's pose-graph interface -> the monitor's keyframe estimate (stamps (M,), poses (M, 3)).

Since pull request 818 (November 2025) slam_toolbox publishes (facts and source references in
docs/slam_bridges.md):

- `slam_toolbox/new_node_event` (NewNodeEvent): one per node added to the graph, with the
  node's id, the stamp of the scan it was built from and its pose at that moment;
- `slam_toolbox/loop_closure_event` (LoopClosureEvent): a stamp, when the mapper closed a loop
  (every node may have moved);
- `slam_toolbox/pose_graph` (PoseGraph): every node's id and full current pose, headings
  included, published some time after a loop closure (at the next tick of its visualisation
  loop), stamped with its clock.

So no heading has to be recovered: the node events name the scans (node id -> scan stamp) and
give each node's pose until a graph gives a newer one; a graph replaces the pose of every node
it holds. Nodes created after the graph was built are not in it and keep their event poses;
a node that was in the graphs and is missing from a later one whose ids go past it was removed
(lifelong mapping) and is dropped.

Between a loop closure and the graph that shows it, the nodes added meanwhile carry corrected
poses while the older ones still have their poses from before: that mixed map is not a map
slam_toolbox ever held, so estimates are withheld (`waiting`) from a loop-closure event until a
graph stamped at or after it arrives (both stamps come from slam_toolbox's node clock).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PoseGraphCounts:
    """What the bridge holds and could not use, for diagnostics and reports."""

    keyframes: int  # nodes with their scan's stamp and a pose
    nodes_without_stamp: int  # graph nodes whose new-node event never came: left out
    graphs: int  # pose graphs taken
    loop_closures: int  # loop-closure events taken
    removed_nodes: int  # nodes dropped because a graph no longer held them
    waiting_for_graph: bool  # a loop closure was announced and its graph has not come


class PoseGraphBridge:
    """Keyframes from slam_toolbox's NewNodeEvent, LoopClosureEvent and PoseGraph messages.

    `add_node`, `loop_closure` and `update_graph` take them in arrival order; `keyframes()`
    is the current estimate of every node whose scan stamp is known, in id order, and
    `waiting` says whether it should be withheld (module docstring). Invalid input raises
    ValueError and leaves the state unchanged.
    """

    def __init__(self) -> None:
        self._stamps: dict[int, float] = {}  # node id -> stamp of its scan
        self._nodes_of_stamp: dict[float, int] = {}
        self._poses: dict[int, np.ndarray] = {}  # node id -> newest pose
        self._in_graph: set[int] = set()  # nodes whose pose came from a graph
        self._newest_graph = -math.inf  # header stamp of the newest graph
        self._closed_at: float | None = None  # stamp of a loop closure awaiting its graph
        self._graphs = 0
        self._loop_closures = 0
        self._removed = 0

    def add_node(self, node_id: int, stamp: float, pose: np.ndarray) -> bool:
        """Take a new-node event.

        Parameters
        ----------
        node_id: the node's id in the graph.
        stamp: the stamp of the scan it was built from, seconds.
        pose: (3,) its pose (x, y, yaw) when it was added; a graph's pose of the node, when
            one came first, is kept.

        Returns
        -------
        True when taken, False when it repeats one already taken (same id and stamp).
        ValueError for a non-finite stamp or pose, a known id with another stamp (a restarted
        session reuses ids: the stamps say which scan, so one id cannot name two) and for a
        stamp already naming another node (each node is built from its own scan).
        """
        node_id = int(node_id)
        pose = np.asarray(pose, dtype=np.float64).reshape(3)
        if not (math.isfinite(stamp) and np.all(np.isfinite(pose))):
            raise ValueError(f'node {node_id}: non-finite stamp or pose')
        known = self._stamps.get(node_id)
        if known is not None:
            if known == stamp:
                return False
            raise ValueError(f'node {node_id} was announced with the scan stamped {known:.6f} '
                             f'and again with {stamp:.6f} (a restarted slam_toolbox session '
                             'numbers its nodes from 0 again)')
        other = self._nodes_of_stamp.get(stamp)
        if other is not None:
            raise ValueError(f'node {node_id} has the scan stamp {stamp:.6f} of node {other} '
                             "(slam_toolbox's synchronous node stamps its events with the "
                             'newest scan received, not the one processed)')
        self._stamps[node_id] = stamp
        self._nodes_of_stamp[stamp] = node_id
        if node_id not in self._in_graph:  # a graph's pose is newer than the event's
            self._poses[node_id] = pose
        return True

    def loop_closure(self, stamp: float) -> None:
        """A loop-closure event: withhold estimates until a graph built after it arrives
        (one that already arrived, the topics being unordered, ends the wait at once).

        Parameters
        ----------
        stamp: the event's stamp, seconds of slam_toolbox's clock (ValueError if not finite).
        """
        if not math.isfinite(stamp):
            raise ValueError('loop closure event with a non-finite stamp')
        self._loop_closures += 1
        if stamp > self._newest_graph:
            self._closed_at = stamp if self._closed_at is None else max(self._closed_at, stamp)

    def update_graph(self, ids: np.ndarray, poses: np.ndarray, stamp: float) -> None:
        """Take a full pose graph.

        Parameters
        ----------
        ids: (V,) node ids, none repeated.
        poses: (V, 3) their poses (x, y, yaw), finite.
        stamp: the message's header stamp, seconds of slam_toolbox's clock; a non-finite one
            ends no wait for a loop closure.

        ValueError (state unchanged) for a count mismatch, repeated ids or non-finite poses.
        """
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        if len(ids) != len(poses):
            raise ValueError(f'{len(ids)} node ids for {len(poses)} poses')
        if len(np.unique(ids)) != len(ids) or not np.all(np.isfinite(poses)):
            raise ValueError('pose graph with repeated node ids or non-finite poses')
        if len(ids):
            held = set(ids.tolist())
            newest = int(ids.max())
            # every node up to the graph's newest existed when it was built
            gone = [node for node in self._poses if node <= newest and node not in held]
            for node in gone:
                self._forget(node)
            self._removed += len(gone)
            for node, pose in zip(ids.tolist(), poses):
                self._poses[node] = pose.copy()
            self._in_graph = held
        self._graphs += 1
        if math.isfinite(stamp):
            self._newest_graph = max(self._newest_graph, stamp)
            if self._closed_at is not None and stamp >= self._closed_at:
                self._closed_at = None

    def _forget(self, node: int) -> None:
        self._poses.pop(node, None)
        stamp = self._stamps.pop(node, None)
        if stamp is not None:
            self._nodes_of_stamp.pop(stamp, None)

    @property
    def waiting(self) -> bool:
        """Whether a loop closure was announced whose graph has not arrived."""
        return self._closed_at is not None

    def keyframes(self) -> tuple[np.ndarray, np.ndarray]:
        """The current estimate (see `waiting` for whether to use it).

        Returns
        -------
        (stamps (M,), poses (M, 3)) of every node with its scan's stamp, in id order.
        """
        nodes = sorted(node for node in self._poses if node in self._stamps)
        stamps = np.array([self._stamps[node] for node in nodes], dtype=np.float64)
        poses = (np.array([self._poses[node] for node in nodes]) if nodes
                 else np.zeros((0, 3)))
        return stamps, poses

    @property
    def counts(self) -> PoseGraphCounts:
        without_stamp = sum(1 for node in self._poses if node not in self._stamps)
        return PoseGraphCounts(
            keyframes=len(self._poses) - without_stamp, nodes_without_stamp=without_stamp,
            graphs=self._graphs, loop_closures=self._loop_closures,
            removed_nodes=self._removed, waiting_for_graph=self.waiting)
