"""Launch the map_consistency node beside a SLAM stack.

    ros2 launch map_consistency_ros map_consistency.launch.py \
        namespace:=robot1 use_sim_time:=true scan_topic:=/base_scan trajectory_topic:=/slam/path

Arguments: namespace, params_file (default: the shipped config/map_consistency.yaml),
use_sim_time, log_level, and the remappings of the node's inputs (scan_topic,
trajectory_topic, pose_topic, constraints_topic). Which pose topic is read is the parameter
pose_source (docs/node.md).
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

PACKAGE = 'map_consistency_ros'

ARGUMENTS = (
    ('namespace', '', 'namespace of the node and its topics'),
    ('params_file', PathJoinSubstitution([FindPackageShare(PACKAGE), 'config',
                                          'map_consistency.yaml']),
     'ROS 2 parameter file of the node'),
    ('use_sim_time', 'false', 'follow /clock (a bag played with --clock)'),
    ('log_level', 'info', 'log level of the node'),
    ('scan_topic', 'scan', 'sensor_msgs/LaserScan input'),
    ('trajectory_topic', 'trajectory', 'nav_msgs/Path keyframe estimate (pose_source: path)'),
    ('pose_topic', 'pose', 'single poses (pose_source: odometry | pose | pose_with_covariance)'),
    ('constraints_topic', 'constraints', 'std_msgs/Float64MultiArray pose-graph edges'),
)


def generate_launch_description() -> LaunchDescription:
    arguments = [DeclareLaunchArgument(name, default_value=default, description=description)
                 for name, default, description in ARGUMENTS]
    node = Node(
        package=PACKAGE, executable='map_consistency_node', name='map_consistency',
        namespace=LaunchConfiguration('namespace'), output='screen',
        parameters=[LaunchConfiguration('params_file'),
                    {'use_sim_time': LaunchConfiguration('use_sim_time')}],
        arguments=['--ros-args', '--log-level', LaunchConfiguration('log_level')],
        remappings=[('scan', LaunchConfiguration('scan_topic')),
                    ('trajectory', LaunchConfiguration('trajectory_topic')),
                    ('pose', LaunchConfiguration('pose_topic')),
                    ('constraints', LaunchConfiguration('constraints_topic'))])
    return LaunchDescription(arguments + [node])
