"""slam_toolbox's pose-graph messages (shipped definitions) <-> records: the byte reader of
PoseGraph against the deserialized message, on real Intel poses."""
import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from map_consistency_ros.io import messages


@pytest.fixture(scope='module')
def typestore():
    store = get_typestore(Stores.ROS2_JAZZY)
    messages.register_slam_toolbox_types(store)
    return store


def types_of(store):
    return lambda name: store.types[name]


@pytest.mark.parametrize('frame_id', ['map', 'a_longer_map_frame', ''])
def test_pose_graph_bytes_read_as_the_deserialized_message(typestore, frame_id,
                                                           slam_toolbox_stream):
    poses = slam_toolbox_stream.final
    ids = np.arange(len(poses)) + 7
    message = messages.pose_graph_message(types_of(typestore), 12.5, ids, poses, frame_id,
                                          edges=np.column_stack([ids[:-1], ids[1:]]))
    data = bytes(typestore.serialize_cdr(message, messages.POSE_GRAPH_TYPE))
    from_bytes = messages.pose_graph_from_cdr(data)
    deserialized = messages.to_record(messages.POSE_GRAPH_TYPE,
                                      typestore.deserialize_cdr(data, messages.POSE_GRAPH_TYPE))
    for record in (from_bytes, deserialized):
        np.testing.assert_array_equal(record.ids, ids)
        np.testing.assert_allclose(record.poses, poses, atol=1e-12)
        assert (record.stamp, record.frame_id) == (12.5, frame_id)
    with pytest.raises(ValueError, match='do not fit'):
        messages.pose_graph_from_cdr(data[:len(data) // 8])  # within the nodes


def test_empty_graph_and_repeated_ids(typestore):
    types = types_of(typestore)
    empty = typestore.serialize_cdr(messages.pose_graph_message(types, 1.0, np.zeros(0),
                                                                np.zeros((0, 3))),
                                    messages.POSE_GRAPH_TYPE)
    record = messages.pose_graph_from_cdr(bytes(empty))
    assert record.ids.size == 0 and record.poses.shape == (0, 3)
    repeated = typestore.serialize_cdr(messages.pose_graph_message(
        types, 1.0, np.array([3, 3]), np.zeros((2, 3))), messages.POSE_GRAPH_TYPE)
    with pytest.raises(ValueError, match='more than once'):
        messages.pose_graph_from_cdr(bytes(repeated))


def test_new_node_event_record(typestore):
    event = messages.new_node_event_message(types_of(typestore), 4, 976052857.3375,
                                            np.array([1.0, -2.0, 3.0]))
    record = messages.to_record(messages.NEW_NODE_EVENT_TYPE, event)
    assert record.node_id == 4 and abs(record.stamp - 976052857.3375) < 1e-6
    np.testing.assert_allclose(record.pose, [1.0, -2.0, 3.0])
    assert messages.to_record(messages.LOOP_CLOSURE_EVENT_TYPE,
                              messages.loop_closure_event_message(types_of(typestore),
                                                                  5.0)).stamp == 5.0
