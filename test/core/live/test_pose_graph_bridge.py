"""PoseGraphBridge: slam_toolbox's node events, loop-closure events and pose graphs in the orders
two unordered topics can bring them (poses from the real Intel trajectory)."""
import numpy as np
import pytest

from map_consistency_ros.core.geometry import se2
from map_consistency_ros.core.live import PoseGraphBridge
from map_consistency_ros.io.carmen import read_carmen_log

NODES = 30


@pytest.fixture(scope='module')
def trajectory(shared_data):
    log = read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    order = np.argsort(log.timestamps[:NODES], kind='stable')
    poses = log.laser_poses[:NODES][order]
    turned = se2.compose(np.broadcast_to(np.array([0.5, -0.2, 0.2]), poses.shape), poses)
    return log.timestamps[:NODES][order], poses, turned


def test_graph_replaces_event_poses_and_later_events_stay(trajectory):
    stamps, poses, turned = trajectory
    bridge = PoseGraphBridge()
    for node in range(NODES):
        assert bridge.add_node(node, stamps[node], poses[node])
    bridge.loop_closure(100.0)
    assert bridge.waiting
    bridge.update_graph(np.arange(20), turned[:20], 101.0)
    assert not bridge.waiting
    got_stamps, got = bridge.keyframes()
    np.testing.assert_array_equal(got_stamps, stamps)
    np.testing.assert_array_equal(got[:20], turned[:20])  # headings included
    np.testing.assert_array_equal(got[20:], poses[20:])  # built after the graph: event poses
    # a late event of a node the graph holds keeps the graph's pose; a repeat is no change
    assert not bridge.add_node(5, stamps[5], poses[5])
    np.testing.assert_array_equal(bridge.keyframes()[1][5], turned[5])


def test_graph_before_its_loop_closure_event_and_nodes_without_event(trajectory):
    stamps, poses, turned = trajectory
    bridge = PoseGraphBridge()
    for node in range(10):
        bridge.add_node(node, stamps[node], poses[node])
    bridge.update_graph(np.arange(12), turned[:12], 50.0)  # overtook its event and 2 nodes
    bridge.loop_closure(49.0)
    assert not bridge.waiting
    assert bridge.counts.nodes_without_stamp == 2 and bridge.counts.keyframes == 10
    bridge.add_node(11, stamps[11], poses[11])
    got_stamps, got = bridge.keyframes()
    np.testing.assert_array_equal(got_stamps, stamps[[*range(10), 11]])
    np.testing.assert_array_equal(got[-1], turned[11])


def test_removed_nodes_and_refused_events(trajectory):
    stamps, poses, turned = trajectory
    bridge = PoseGraphBridge()
    for node in range(10):
        bridge.add_node(node, stamps[node], poses[node])
    kept = np.array([0, 1, 2, 5, 6, 7, 8])  # lifelong mapping removed 3 and 4; 9 came after
    bridge.update_graph(kept, turned[kept], 1.0)
    assert bridge.counts.removed_nodes == 2
    np.testing.assert_array_equal(bridge.keyframes()[0], stamps[[0, 1, 2, 5, 6, 7, 8, 9]])
    with pytest.raises(ValueError, match='scan stamp'):
        bridge.add_node(20, stamps[9], poses[9])  # synchronous mode: the newest scan's stamp
    with pytest.raises(ValueError, match='again'):
        bridge.add_node(9, stamps[12], poses[12])  # a restarted session reuses the id
    with pytest.raises(ValueError):
        bridge.update_graph(np.array([1, 1]), turned[:2], 2.0)
    assert bridge.counts.keyframes == 8
