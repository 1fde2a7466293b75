"""The rclpy edge: message conversion, the live node, publishing helpers."""
