"""slam_toolbox (online async) and the map_consistency node reading its poses and graph.

    ros2 launch map_consistency_ros slam_toolbox_consistency.launch.py use_sim_time:=true

slam_toolbox publishes `pose` (geometry_msgs/PoseWithCovarianceStamped, map frame, one per
accepted scan, stamped like that scan) and `slam_toolbox/graph_visualization` (its graph
vertices' positions). With pose_source slam_toolbox the node bridges the two into the full
keyframe estimate, loop-closure corrections included (docs/node.md, "Keyframes from
slam_toolbox"). The node is started with slam_toolbox here; it must be subscribed before
slam_toolbox accepts its first scan, since the bridge counts `pose` messages from the first.
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, IncludeLaunchDescription
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare


def generate_launch_description() -> LaunchDescription:
    use_sim_time = LaunchConfiguration('use_sim_time')
    slam = IncludeLaunchDescription(
        PythonLaunchDescriptionSource(PathJoinSubstitution(
            [FindPackageShare('slam_toolbox'), 'launch', 'online_async_launch.py'])),
        launch_arguments={'use_sim_time': use_sim_time}.items())
    consistency = Node(
        package='map_consistency_ros', executable='map_consistency_node',
        name='map_consistency', output='screen',
        parameters=[PathJoinSubstitution([FindPackageShare('map_consistency_ros'), 'config',
                                          'map_consistency.yaml']),
                    {'use_sim_time': use_sim_time, 'pose_source': 'slam_toolbox',
                     'frame_id': 'map'}],
        remappings=[('pose', '/pose'), ('scan', '/scan'),
                    ('graph_visualization', '/slam_toolbox/graph_visualization')])
    return LaunchDescription([
        DeclareLaunchArgument('use_sim_time', default_value='false',
                              description='follow /clock (a bag played with --clock)'),
        slam, consistency])
