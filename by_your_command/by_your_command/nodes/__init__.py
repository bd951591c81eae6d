"""rclpy nodes: thin adapters between ROS topics/parameters and the pure classes.

This is the only package (with `ros/`) allowed to import rclpy; a test enforces it.
"""
