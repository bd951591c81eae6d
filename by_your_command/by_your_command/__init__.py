"""by_your_command: talk to robots. Pure-Python core; rclpy lives only in `nodes/`."""

__version__ = "0.1.0"
