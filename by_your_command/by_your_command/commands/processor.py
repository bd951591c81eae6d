"""Message in, one verdict per command out: grammar, safety gate and routing together (no ROS).

A `stop` goes first: its verdicts lead the list (so the node publishes it before anything else in
the message), and commands written before it in the same message are refused as superseded, so
"reach, stop" can never end with the arm reaching. Commands after the last stop keep their order.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from by_your_command.commands.grammar import CommandGrammar, MessageLimits, Parsed, is_stop
from by_your_command.commands.routing import Route, route
from by_your_command.commands.safety import SafetyConfig, SafetyGate, allow_list
from by_your_command.commands.vocabulary import Vocabulary, load_vocabulary


@dataclass(frozen=True)
class Verdict:
    raw: str
    command: str  # normal form; "" when the text was not a valid command
    accepted: bool
    reason: str  # why it was refused, or what it is when accepted
    route: Route | None  # where to publish it; None when refused


SUPERSEDED = "superseded by a later 'stop' in the same message"


@dataclass
class ProcessorStats:
    messages: int = 0
    oversize_messages: int = 0  # longer than max_message_chars: refused unparsed
    superseded: int = 0  # commands cancelled by a later stop in their message


class CommandProcessor:
    def __init__(
        self, vocabulary: Vocabulary, safety: SafetyConfig, limits: MessageLimits | None = None
    ) -> None:
        self.grammar = CommandGrammar(vocabulary, limits)
        self.gate = SafetyGate(safety)
        self.stats = ProcessorStats()
        unknown = sorted((safety.allowed or frozenset()) - set(vocabulary.commands))
        if unknown:
            raise ValueError(f"allow-list names unknown commands: {', '.join(unknown)}")

    def process(self, message: str, now: float) -> list[Verdict]:
        self.stats.messages += 1
        if len(message) > self.grammar.limits.max_message_chars:
            self.stats.oversize_messages += 1
        pieces = self.grammar.parse_message(message)
        stops = [index for index, parsed in enumerate(pieces) if is_stop(parsed)]
        if not stops:
            return [self._judge(parsed, now) for parsed in pieces]
        last_stop = stops[-1]
        verdicts = [self._judge(pieces[index], now) for index in stops]
        for index, parsed in enumerate(pieces):
            if is_stop(parsed):
                continue
            if index < last_stop and parsed.command is not None:
                self.stats.superseded += 1
                verdicts.append(Verdict(parsed.raw, parsed.command.text, False, SUPERSEDED, None))
            else:
                verdicts.append(self._judge(parsed, now))
        return verdicts

    def _judge(self, parsed: Parsed, now: float) -> Verdict:
        command = parsed.command
        if command is None:
            return Verdict(parsed.raw, "", False, parsed.reason, None)
        refusal = self.gate.check(command, now)
        if refusal:
            return Verdict(parsed.raw, command.text, False, refusal, None)
        reason = f"{command.spec.category.value} command"
        return Verdict(parsed.raw, command.text, True, reason, route(command))


_LIMITS = MessageLimits()


@dataclass(frozen=True)
class CommandProcessorConfig:
    """Parameters of the command_processor node (the one place their defaults live)."""

    input_topic: str = field(default="response_cmd", metadata={"help": "commands from the agents (String)"})
    request_topic: str = field(
        default="command_request",
        metadata={"help": "commands whose verdicts carry the caller's request_id (CommandRequest)"},
    )
    arm_topic: str = field(default="arm_preset", metadata={"help": "accepted arm presets go here (String)"})
    behavior_topic: str = field(
        default="behavior_command", metadata={"help": "accepted behaviors go here (String)"}
    )
    wake_topic: str = field(default="wake_cmd", metadata={"help": "sleep -> False, wake -> True (Bool)"})
    status_topic: str = field(
        default="command_status", metadata={"help": "one CommandVerdict per command found"}
    )
    commands_file: str = field(
        default="", metadata={"help": "commands.yaml vocabulary; empty = the one installed with the package"}
    )
    allowed_commands: list[str] = field(
        default_factory=list,
        metadata={"help": "allow-list of command bases; empty = all (stop always allowed)"},
    )
    min_interval_s: float = field(
        default=1.0, metadata={"help": "refuse the same command repeated within this time; 0 = off"}
    )
    max_message_chars: int = field(
        default=_LIMITS.max_message_chars,
        metadata={"help": "a longer message gets one refused verdict, unparsed (a stop in it still counts)"},
    )
    max_commands_per_message: int = field(
        default=_LIMITS.max_pieces,
        metadata={"help": "pieces (commands or chatter) parsed per message; the rest get one verdict"},
    )

    def __post_init__(self) -> None:
        for name in (
            "input_topic",
            "request_topic",
            "arm_topic",
            "behavior_topic",
            "wake_topic",
            "status_topic",
        ):
            if not getattr(self, name).strip():
                raise ValueError(f"{name} must not be empty")
        SafetyConfig(min_interval_s=self.min_interval_s)  # validates the interval
        self.limits()  # validates the bounds

    def limits(self) -> MessageLimits:
        return MessageLimits(self.max_message_chars, self.max_commands_per_message)

    def build(self) -> CommandProcessor:
        vocabulary = load_vocabulary(self.commands_file or None)
        safety = SafetyConfig(allow_list(self.allowed_commands), self.min_interval_s)
        return CommandProcessor(vocabulary, safety, self.limits())
