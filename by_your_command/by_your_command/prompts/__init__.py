"""Prompt library: prompts.yaml loading and validation, `{{macro}}` expansion, prompt selection (no rclpy)."""
