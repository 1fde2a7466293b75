"""The live state: the input records (scans, keyframe estimates, single poses, graph snapshots,
constraints, dropped scans), the one feed from records to the monitor (keyframing of single
poses, resets, stamp gaps) and its account of every scan received (ScanCounts), the pose
sources behind it (the slam_toolbox graph-marker bridge and its PoseGraph bridge),
ConsistencyMonitor, the incremental state (pair cache, placed geometry), and the live
pipeline over them all (feed, monitor, both stages), shared by the node, replay and the
warm-up. `monitor` and `pipeline` stay public modules: tests patch them."""
from map_consistency_ros.core.live._feed import (KEYFRAMED_SOURCES, POSE_SOURCES,
                                                 RESET_CONFIRMATIONS, Applied, FeedSettings,
                                                 MonitorFeed, PoseKeyframer, PoseSource, ScanGaps)
from map_consistency_ros.core.live._graph_bridge import (BridgeCounts, BridgeSettings,
                                                         HeadingFit, SlamToolboxBridge,
                                                         fit_rotations, interpolate_rotations,
                                                         neighbourhoods)
from map_consistency_ros.core.live._pose_graph_bridge import PoseGraphBridge, PoseGraphCounts
from map_consistency_ros.core.live._records import (Constraints, DroppedScans, GraphSnapshot,
                                                    KeyframeEstimate, LoopClosure, NodeEvent,
                                                    PoseGraphNodes, PoseSample, Record, Scan)
from map_consistency_ros.core.live._scan_counts import ScanCounts
from map_consistency_ros.core.live.monitor import (ConsistencyMonitor, MonitorSettings,
                                                   MonitorSnapshot, SlamGraph, UpdateSummary,
                                                   sensor_poses)
from map_consistency_ros.core.live.pipeline import LivePipeline, LiveVerdict, Retune, warm_up

__all__ = [
    'Scan', 'KeyframeEstimate', 'PoseSample', 'Constraints', 'GraphSnapshot', 'Record',
    'NodeEvent', 'PoseGraphNodes', 'LoopClosure', 'DroppedScans', 'ScanCounts',
    'PoseGraphBridge', 'PoseGraphCounts',
    'FeedSettings', 'MonitorFeed', 'Applied', 'PoseKeyframer', 'ScanGaps', 'warm_up',
    'PoseSource', 'POSE_SOURCES', 'KEYFRAMED_SOURCES', 'RESET_CONFIRMATIONS',
    'BridgeSettings', 'BridgeCounts', 'HeadingFit', 'SlamToolboxBridge', 'neighbourhoods',
    'fit_rotations', 'interpolate_rotations',
    'ConsistencyMonitor', 'MonitorSettings', 'MonitorSnapshot', 'UpdateSummary', 'sensor_poses',
    'LivePipeline', 'LiveVerdict', 'SlamGraph', 'Retune',
]
