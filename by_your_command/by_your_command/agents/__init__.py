"""Agent runtime (no ROS): provider sessions, turns, barge-in, session cycling, context."""
