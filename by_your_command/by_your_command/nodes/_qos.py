"""The three QoS profiles of the topic contract (DESIGN.md §4)."""

from __future__ import annotations

from rclpy.qos import QoSDurabilityPolicy, QoSHistoryPolicy, QoSProfile, QoSReliabilityPolicy

# Streaming audio/video: a late sample is worthless, never block the publisher.
STREAM = QoSProfile(
    history=QoSHistoryPolicy.KEEP_LAST, depth=10, reliability=QoSReliabilityPolicy.BEST_EFFORT
)
# Subscribers of streaming audio: best effort too, but a deeper queue than STREAM's. Downstream a
# lost block is a gap (the VAD and echo control restart their timelines there), so a scheduling
# stall of up to ~4 s of 64 ms blocks is absorbed instead of lost.
AUDIO_IN = QoSProfile(
    history=QoSHistoryPolicy.KEEP_LAST, depth=64, reliability=QoSReliabilityPolicy.BEST_EFFORT
)
# Utterance chunks, commands, signals: every message matters.
RELIABLE = QoSProfile(
    history=QoSHistoryPolicy.KEEP_LAST, depth=100, reliability=QoSReliabilityPolicy.RELIABLE
)
# State (attention_state, assistant_speaking...): a late joiner gets the current value.
LATCHED = QoSProfile(
    history=QoSHistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=QoSReliabilityPolicy.RELIABLE,
    durability=QoSDurabilityPolicy.TRANSIENT_LOCAL,
)
