"""`map-consistency replay` of slam_toolbox's pose-graph interface (NewNodeEvent, LoopClosureEvent,
PoseGraph) built from real Intel scans: the verdict of `check` on the same poses."""
import numpy as np
import pytest

from map_consistency_ros.cli.main import main
from map_consistency_ros.core.live import NodeEvent, PoseGraphNodes
from map_consistency_ros.io import messages
from map_consistency_ros.io.bags import BagReader
from test.conftest import write_graph_bag


def write_carmen(path, stamps, ranges, poses):
    """A CARMEN log of the scans at `poses` (laser poses), in stamp order."""
    lines = []
    for stamp, scan, pose in zip(stamps, ranges, poses):
        values = ' '.join(repr(float(r)) for r in scan)
        pose_text = ' '.join(repr(float(v)) for v in pose)
        stamp = repr(float(stamp))
        lines.append(f'FLASER {len(scan)} {values} {pose_text} {pose_text} {stamp} host '
                     f'{stamp}\n')
    path.write_text(''.join(lines))
    return path


@pytest.fixture(scope='module')
def graph_bag(rotated_graph_stream, tmp_path_factory):
    return write_graph_bag(tmp_path_factory.mktemp('graph') / 'bag', rotated_graph_stream)


def test_replay_gives_the_verdict_of_check_on_the_graph_poses(strict_json, graph_bag,
                                                               rotated_graph_stream, tmp_path):
    # The loop closure turns every node and its heading: the node events before it carry
    # the old headings, only the graph the new ones. `check` of the final poses judges the
    # same map (a check log's poses are its incremental solution too, and the turn leaves
    # every step between nodes as it was).
    stream = rotated_graph_stream
    count = len(stream.stamps)
    # every pair, as check measures them (the node's partner budget thins a crowded place)
    params = tmp_path / 'params.yaml'
    params.write_text('/map_consistency:\n  ros__parameters:\n    max_partners: 0\n')
    replayed = main(['replay', str(graph_bag), '--quiet', '--params-file', str(params),
                     '--report', str(tmp_path / 'r.json')])
    log = write_carmen(tmp_path / 'final.log', stream.stamps, stream.ranges, stream.final)
    checked = main(['check', str(log), '--quiet', '--report', str(tmp_path / 'c.json')])
    report = strict_json((tmp_path / 'r.json').read_text())
    check_report = strict_json((tmp_path / 'c.json').read_text())
    assert report['topics']['pose_type'] == messages.NEW_NODE_EVENT_TYPE
    assert report['topics']['pose_graph'] == '/slam_toolbox/pose_graph'
    assert report['node_parameters']['pose_source'] == 'slam_toolbox_graph'
    assert (report['replay']['node_events'], report['replay']['pose_graphs'],
            report['replay']['loop_closures'], report['replay']['warnings']) == (count, 1, 1, [])
    assert report['slam_toolbox_bridge'] == {
        'keyframes': count, 'nodes_without_stamp': 0, 'graphs': 1, 'loop_closures': 1,
        'removed_nodes': 0, 'waiting_for_graph': False}
    assert replayed == checked == (0 if check_report['verdict'] == 'consistent' else 1)
    assert report['verdict'] == check_report['verdict']
    # every figure of the verdict; candidate_pairs is how many pairs each kept after its
    # extent test (the monitor keeps only the overlapping ones), a cost, not a verdict
    summary, expected = dict(report['summary']), dict(check_report['summary'])
    summary.pop('candidate_pairs'), expected.pop('candidate_pairs')
    assert summary == expected
    assert report['summary_line'] == check_report['summary_line']
    counts = report['replay']['scan_counts']
    assert counts['keyframes'] + counts['folded'] == count


def test_the_graph_headings_decide_the_verdict(strict_json, graph_bag, rotated_graph_stream,
                                               tmp_path):
    # the same positions with the headings of the node events (before the turn): another map
    stream = rotated_graph_stream
    positions_only = stream.final.copy()
    positions_only[:, 2] = stream.poses[:, 2]
    log = write_carmen(tmp_path / 'headings.log', stream.stamps, stream.ranges, positions_only)
    main(['check', str(log), '--quiet', '--report', str(tmp_path / 'c.json')])
    main(['replay', str(graph_bag), '--quiet', '--report', str(tmp_path / 'r.json')])
    wrong = strict_json((tmp_path / 'c.json').read_text())['summary']
    right = strict_json((tmp_path / 'r.json').read_text())['summary']
    assert wrong['failed_pairs'] > 2 * right['failed_pairs']


def test_estimates_wait_for_the_graph_of_a_loop_closure(strict_json, slam_toolbox_graph_stream,
                                                        tmp_path):
    # Cut just before the graph: the node events after the loop closure carry moved poses,
    # the older nodes do not yet; that mix is withheld, the map stays the one before the closure.
    stream = slam_toolbox_graph_stream
    cut = next(index for index, (_, kind, _) in enumerate(stream.messages) if kind == 'graph')
    bag = write_graph_bag(tmp_path / 'cut', stream, messages_until=cut)
    main(['replay', str(bag), '--quiet', '--report', str(tmp_path / 'r.json')])
    report = strict_json((tmp_path / 'r.json').read_text())
    assert report['slam_toolbox_bridge']['waiting_for_graph'] is True
    assert report['slam_toolbox_bridge']['keyframes'] == stream.graph_after + 1
    # the map judged is the last one before the closure: nodes 0 .. loop - 1
    assert report['judged_stamp'] == stream.stamps[stream.loop - 1]
    assert report['judged_keyframes'] + report['replay']['scan_counts']['folded'] == stream.loop


def test_bag_holds_slam_toolbox_messages_from_the_shipped_definitions(graph_bag,
                                                                      rotated_graph_stream):
    # written and read with the shipped definitions; the graph's headings come back intact
    stream = rotated_graph_stream
    with BagReader([graph_bag]) as bag:
        assert bag.pose_topic == '/slam_toolbox/new_node_event'
        assert bag.input_topics == ['/scan', '/slam_toolbox/new_node_event', '/constraints',
                                    '/slam_toolbox/pose_graph',
                                    '/slam_toolbox/loop_closure_event']
        records = [record for _, record in bag.records()]
    graphs = [record for record in records if isinstance(record, PoseGraphNodes)]
    assert len(graphs) == 1 and graphs[0].frame_id == 'map'
    np.testing.assert_array_equal(graphs[0].ids, np.arange(stream.graph_after + 1))
    np.testing.assert_allclose(graphs[0].poses, stream.final[:stream.graph_after + 1],
                               atol=1e-12)
    events = [record for record in records if isinstance(record, NodeEvent)]
    np.testing.assert_array_equal([event.stamp for event in events], stream.stamps)
