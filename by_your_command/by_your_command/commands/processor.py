"""Message in, one verdict per command out: grammar, safety gate and routing together (no ROS)."""

from __future__ import annotations

from dataclasses import dataclass, field

from by_your_command.commands.grammar import CommandGrammar
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


class CommandProcessor:
    def __init__(self, vocabulary: Vocabulary, safety: SafetyConfig) -> None:
        self.grammar = CommandGrammar(vocabulary)
        self.gate = SafetyGate(safety)
        unknown = sorted((safety.allowed or frozenset()) - set(vocabulary.commands))
        if unknown:
            raise ValueError(f"allow-list names unknown commands: {', '.join(unknown)}")

    def process(self, message: str, now: float) -> list[Verdict]:
        verdicts = []
        for parsed in self.grammar.parse_message(message):
            command = parsed.command
            if command is None:
                verdicts.append(Verdict(parsed.raw, "", False, parsed.reason, None))
                continue
            refusal = self.gate.check(command, now)
            if refusal:
                verdicts.append(Verdict(parsed.raw, command.text, False, refusal, None))
                continue
            target = route(command)
            reason = f"{command.spec.category.value} command"
            verdicts.append(Verdict(parsed.raw, command.text, True, reason, target))
        return verdicts


@dataclass(frozen=True)
class CommandProcessorConfig:
    """Parameters of the command_processor node (the one place their defaults live)."""

    input_topic: str = field(default="response_cmd", metadata={"help": "commands from the agents (String)"})
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

    def __post_init__(self) -> None:
        for name in ("input_topic", "arm_topic", "behavior_topic", "wake_topic", "status_topic"):
            if not getattr(self, name).strip():
                raise ValueError(f"{name} must not be empty")
        SafetyConfig(min_interval_s=self.min_interval_s)  # validates the interval

    def build(self) -> CommandProcessor:
        vocabulary = load_vocabulary(self.commands_file or None)
        return CommandProcessor(
            vocabulary, SafetyConfig(allow_list(self.allowed_commands), self.min_interval_s)
        )
