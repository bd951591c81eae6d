"""ROS helpers that need rclpy or rosidl introspection (allowed to import ROS, unlike the core)."""
