"""Robot command vocabulary, grammar, routing and safety checks (no rclpy)."""
