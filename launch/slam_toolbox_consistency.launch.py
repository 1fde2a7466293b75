"""slam_toolbox (online async) and the map_consistency node reading its poses.

    ros2 launch map_consistency_ros slam_toolbox_consistency.launch.py use_sim_time:=true

slam_toolbox publishes `pose` (geometry_msgs/PoseWithCovarianceStamped, map frame, stamped
like the scan it processed): the node takes it with pose_source pose_with_covariance and picks
keyframes by travelled distance / turned angle, as replay does. Its graph markers carry vertex
positions only, so loop-closure corrections reach the node through later poses, not through
the graph (docs/node.md, "Pose sources").
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
                    {'use_sim_time': use_sim_time, 'pose_source': 'pose_with_covariance',
                     'frame_id': 'map'}],
        remappings=[('pose', '/pose'), ('scan', '/scan')])
    return LaunchDescription([
        DeclareLaunchArgument('use_sim_time', default_value='false',
                              description='follow /clock (a bag played with --clock)'),
        slam, consistency])
