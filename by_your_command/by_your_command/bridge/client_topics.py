"""Which class (delivery lane) a subscribed topic belongs to, on the agent side without the bridge's YAML."""

from __future__ import annotations

from by_your_command.bridge.config import TopicClass

# The default topic contract (config/bridge.yaml, docs/topics.md), by last name token, so the
# same table serves `prompt_voice`, `/robot1/prompt_voice` and a remapped namespace.
CONTRACT_CLASSES: dict[str, TopicClass] = {
    "prompt_voice": "audio",
    "prompt_text": "text",
    "prompt_transcript": "text",
    "response_text": "text",
    "response_voice": "audio",
    "voice_activity": "state",
    "assistant_speaking": "state",
    "playback_status": "state",
    "attention_state": "state",
    "camera_forwarded": "video",
    "command_status": "command",
    "response_cmd": "command",
    "command_request": "command",
    "interruption_signal": "command",
}


def base_name(topic: str) -> str:
    return topic.rsplit("/", 1)[-1]


def default_class(topic: str, msg_type: str | None = None) -> TopicClass:
    """Contract topics by name; others by type like the bridge does, except that an unknown
    topic is `text` (ordered, never dropped here) rather than latest-wins `state`."""
    known = CONTRACT_CLASSES.get(base_name(topic))
    if known is not None:
        return known
    short = base_name(msg_type or "")
    if "Image" in short:
        return "video"
    if "Audio" in short:
        return "audio"
    return "text"


class TopicClasses:
    """The client's subscriptions and their classes; maps the bridge's report keys back to them."""

    def __init__(self) -> None:
        self._by_topic: dict[str, TopicClass] = {}

    def set(self, topic: str, topic_class: TopicClass) -> None:
        self._by_topic[topic] = topic_class

    def remove(self, topic: str) -> None:
        self._by_topic.pop(topic, None)

    def class_of(self, topic: str) -> TopicClass:
        """Hot path: one dict lookup for subscribed topics."""
        known = self._by_topic.get(topic)
        return known if known is not None else default_class(topic)

    def items(self) -> list[tuple[str, TopicClass]]:
        return list(self._by_topic.items())

    def resolve(self, reported: str) -> str:
        """The subscribed name for a topic the bridge names fully (`/robot1/prompt_voice` for a
        client that subscribed `prompt_voice`); the reported name itself when nothing matches."""
        if reported in self._by_topic:
            return reported
        for topic in self._by_topic:
            if not topic.startswith("/") and reported.endswith("/" + topic):
                return topic
        return reported
