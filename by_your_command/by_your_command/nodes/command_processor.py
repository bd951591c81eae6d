"""command_processor: response_cmd text -> validated robot commands on arm/behavior/wake topics.

Every command found gets a CommandVerdict on command_status (accepted or refused, with the reason).
A CommandRequest (an agent's tool call) is parsed the same way, and each of its verdicts carries
its request_id, index and count, so the caller matches them by identity, never by text.
All the logic is in by_your_command.commands; this node only moves messages. The processor bounds
the work per message (an oversize message costs one linear scan), so a burst of junk cannot keep
a later `stop` waiting; refusals are counted and their log lines rate-limited.
"""

from __future__ import annotations

import time
import traceback

from by_your_command_msgs.msg import CommandRequest, CommandVerdict
from rclpy.node import Node
from rclpy.publisher import Publisher
from std_msgs.msg import Bool, String

from by_your_command.commands.processor import CommandProcessorConfig, Verdict
from by_your_command.commands.routing import Destination
from by_your_command.nodes._params import declare_config
from by_your_command.nodes._qos import RELIABLE
from by_your_command.nodes._runtime import run_node

MAX_REQUEST_ID_CHARS = 128  # a request id is echoed in every verdict: bounded like any input
MAX_VERDICTS = 65535  # index and count are uint16 (the processor bounds the pieces far below this)
REFUSAL_LOG_INTERVAL_S = 1.0  # a flood of junk must not become a flood of log lines (all are counted)


class CommandProcessorNode(Node):
    def __init__(self) -> None:
        super().__init__("command_processor")
        self.config = declare_config(self, CommandProcessorConfig)
        self.processor = self.config.build()
        self.outputs: dict[Destination, Publisher] = {
            Destination.ARM: self.create_publisher(String, self.config.arm_topic, RELIABLE),
            Destination.BEHAVIOR: self.create_publisher(String, self.config.behavior_topic, RELIABLE),
        }
        self.wake = self.create_publisher(Bool, self.config.wake_topic, RELIABLE)
        self.status = self.create_publisher(CommandVerdict, self.config.status_topic, RELIABLE)
        self.create_subscription(String, self.config.input_topic, self.on_text, RELIABLE)
        self.create_subscription(CommandRequest, self.config.request_topic, self.on_request, RELIABLE)
        self.accepted = 0
        self.refused = 0
        self.internal_errors = 0
        self.get_logger().info(
            f"listening on {self.resolve_topic_name(self.config.input_topic)}; "
            f"{len(self.processor.grammar.vocabulary.commands)} commands, "
            f"allow-list {self.config.allowed_commands or 'all'}, "
            f"min interval {self.config.min_interval_s} s, "
            f"at most {self.config.max_message_chars} characters and "
            f"{self.config.max_commands_per_message} pieces per message"
        )

    def on_text(self, message: String) -> None:
        self.guarded("response_cmd", message.data, "")

    def on_request(self, message: CommandRequest) -> None:
        self.guarded("command_request", message.text, message.request_id[:MAX_REQUEST_ID_CHARS])

    def guarded(self, what: str, text: str, request_id: str) -> None:
        try:
            self.process_text(text, request_id)
        except Exception as error:  # a bug, not bad input: an escaping exception would end the node
            self.internal_errors += 1
            self.get_logger().error(
                f"internal error on a {what} message ({self.internal_errors} so far): {error!r}\n"
                + traceback.format_exc(limit=5)
            )

    def process_text(self, text: str, request_id: str = "") -> None:
        verdicts = self.processor.process(text, time.monotonic())  # never none: a caller waits for one
        for index, verdict in enumerate(verdicts):
            topic = ""
            reason = verdict.reason
            accepted = verdict.accepted
            if verdict.route is not None:
                try:
                    topic = self.send(verdict)
                except Exception as error:  # publish() can raise under overload: report, never crash
                    accepted, topic, reason = False, "", f"publish failed: {error}"
            self.report(verdict, accepted, reason, topic, (request_id, index, len(verdicts)))

    def send(self, verdict: Verdict) -> str:
        assert verdict.route is not None
        publisher = self.outputs[verdict.route.destination]
        publisher.publish(String(data=verdict.command))
        if verdict.route.wake is not None:
            self.wake.publish(Bool(data=verdict.route.wake))
        return str(publisher.topic_name)

    def report(
        self, verdict: Verdict, accepted: bool, reason: str, topic: str, place: tuple[str, int, int]
    ) -> None:
        request_id, index, count = place
        status = CommandVerdict(
            raw=verdict.raw,
            command=verdict.command,
            accepted=accepted,
            reason=reason,
            topic=topic,
            request_id=request_id,
            index=min(index, MAX_VERDICTS),
            count=min(count, MAX_VERDICTS),
        )
        status.header.stamp = self.get_clock().now().to_msg()
        self.status.publish(status)
        if accepted:
            self.accepted += 1
            self.get_logger().info(f"{verdict.command} -> {topic}")
        else:
            self.refused += 1
            stats = self.processor.stats
            self.get_logger().warning(
                f"refused {verdict.raw[:80]!r}: {reason} ({self.refused} refused, {self.accepted} accepted, "
                f"{stats.oversize_messages} of {stats.messages} messages oversize)",
                throttle_duration_sec=REFUSAL_LOG_INTERVAL_S,
            )


def main(args: list[str] | None = None) -> None:
    run_node(CommandProcessorNode, args)


if __name__ == "__main__":
    main()
