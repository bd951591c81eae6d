"""What the offline agent says: acknowledgements, answers to its few questions, "did not catch that".

Plain text for Speaker.say; canonical strings come from OfflineRecognizer (`pan@left`, `time`).
"""

from __future__ import annotations

import datetime
from dataclasses import dataclass, field

NOT_CAUGHT = "I did not catch that."


def _default_acknowledgements() -> dict[str, str]:
    return {
        "bumper": "Folding down",
        "tenhut": "Standing at attention",
        "lookup": "Looking up",
        "lookout": "Looking out",
        "reach": "Reaching",
        "pan": "Panning",
        "stop": "Stopping",
        "follow": "Following",
        "track": "Tracking",
        "sleep": "Going to sleep",
        "wake": "I am awake",
        "move": "Moving",
        "turn": "Turning",
    }


@dataclass(frozen=True)
class RepliesConfig:
    robot_name: str = "Barney"
    # Command base -> what the robot says when it accepts it ("Looking up."); others: "OK, <base>."
    acknowledgements: dict[str, str] = field(default_factory=_default_acknowledgements)
    capabilities: str = "I can look around, move, follow you, and tell you the time. Say stop to stop me."


def acknowledgement(canonical: str, config: RepliesConfig) -> str:
    """'pan@full-left' -> 'Panning full left.'; 'follow@me' -> 'Following you.'"""
    base, _, modifier = canonical.partition("@")
    spoken_base = config.acknowledgements.get(base, f"OK, {base}")
    if not modifier:
        return f"{spoken_base}."
    spoken_modifier = "you" if modifier == "me" else modifier.replace("-", " ").replace("_", " ")
    if _is_angle(modifier):
        spoken_modifier = f"{modifier} degrees"
    return f"{spoken_base} {spoken_modifier}."


def _is_angle(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def time_of_day(now: datetime.datetime) -> str:
    """'It is 3 05 PM.' (espeak reads it as "three oh five P M")."""
    hour = now.hour % 12 or 12
    suffix = "AM" if now.hour < 12 else "PM"
    minutes = "o'clock" if now.minute == 0 else f"{now.minute:02d}"
    return f"It is {hour} {minutes} {suffix}."


def answer(question: str, now: datetime.datetime, config: RepliesConfig) -> str:
    """The answer to a question id from the recognizer; NOT_CAUGHT for an unknown id."""
    if question == "time":
        return time_of_day(now)
    if question == "capabilities":
        return config.capabilities
    if question == "identity":
        return (
            f"I am {config.robot_name}, a robot. I am running offline, so I only understand simple commands."
        )
    return NOT_CAUGHT
