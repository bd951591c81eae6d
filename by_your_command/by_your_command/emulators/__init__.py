"""Local stand-ins for cloud realtime APIs (no ROS, no network beyond loopback), for tests and demos."""
