"""Voice activity detection: the Silero ONNX model and the utterance segmenter (no rclpy)."""
