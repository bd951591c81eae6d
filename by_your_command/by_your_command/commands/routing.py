"""Where an accepted command goes: the arm topic, the behavior topic, and maybe wake_cmd."""

from __future__ import annotations

import enum
from dataclasses import dataclass

from by_your_command.commands.grammar import Command
from by_your_command.commands.vocabulary import Category


class Destination(enum.Enum):
    ARM = "arm_preset"
    BEHAVIOR = "behavior_command"


@dataclass(frozen=True)
class Route:
    destination: Destination
    wake: bool | None  # also publish this on wake_cmd (sleep -> False, wake -> True)


ROUTING_TABLE = {Category.ARM: Destination.ARM, Category.BEHAVIOR: Destination.BEHAVIOR}


def route(command: Command) -> Route:
    return Route(ROUTING_TABLE[command.spec.category], command.spec.wake)
