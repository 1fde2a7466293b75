"""Statistical map-consistency test and DCS tuning for 2D-laser SLAM, as a ROS 2 package."""
