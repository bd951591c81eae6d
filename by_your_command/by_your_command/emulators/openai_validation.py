"""What the emulator accepts in client events: known keys, item shapes, content types (GA schema)."""

from __future__ import annotations

from by_your_command.emulators.openai_wire import ClientEventError, JsonObject, decode_pcm, required_str

SESSION_KEYS = {
    "type",
    "model",
    "instructions",
    "output_modalities",
    "audio",
    "tools",
    "tool_choice",
    "max_output_tokens",
    "truncation",
    "tracing",
    "prompt",
    "include",
    "parallel_tool_calls",
    "reasoning",
}
AUDIO_INPUT_KEYS = {"format", "transcription", "noise_reduction", "turn_detection"}
AUDIO_OUTPUT_KEYS = {"format", "voice", "speed"}
RESPONSE_KEYS = {
    "instructions",
    "output_modalities",
    "tools",
    "tool_choice",
    "max_output_tokens",
    "metadata",
    "audio",
    "conversation",
    "input",
    "prompt",
}


def check_keys(value: JsonObject, known: set[str], where: str) -> None:
    for key in value:
        if key not in known:
            raise ClientEventError(
                "unknown_parameter", f"Unknown parameter: '{where}.{key}'.", f"{where}.{key}"
            )


_CONTENT_TYPES = {
    "user": {"input_text", "input_audio", "input_image"},
    "system": {"input_text"},
    "assistant": {"output_text", "output_audio"},
}


def validate_item(item: JsonObject) -> None:
    kind = required_str(item, "type", "item.type")
    if kind == "function_call_output":
        required_str(item, "call_id", "item.call_id")
        required_str(item, "output", "item.output")
        return
    if kind == "function_call":
        for key in ("call_id", "name", "arguments"):
            required_str(item, key, f"item.{key}")
        return
    if kind != "message":
        raise ClientEventError("invalid_value", f"Invalid value for 'item.type': '{kind}'.", "item.type")
    role = required_str(item, "role", "item.role")
    if role not in _CONTENT_TYPES:
        raise ClientEventError("invalid_value", f"Invalid value for 'item.role': '{role}'.", "item.role")
    content = item.get("content")
    if not isinstance(content, list) or not content:
        raise ClientEventError("invalid_value", "'item.content' must be a non-empty list.", "item.content")
    for index, part in enumerate(content):
        where = f"item.content[{index}]"
        if not isinstance(part, dict) or part.get("type") not in _CONTENT_TYPES[role]:
            raise ClientEventError(
                "invalid_value", f"Invalid content type at '{where}' for role {role}.", where
            )
        if part["type"] in ("input_text", "output_text"):
            required_str(part, "text", f"{where}.text")
        elif part["type"] == "input_audio":
            decode_pcm(required_str(part, "audio", f"{where}.audio"), f"{where}.audio")
        elif part["type"] == "input_image":
            url = required_str(part, "image_url", f"{where}.image_url")
            if not url.startswith(("data:image/", "https://", "http://")):
                raise ClientEventError(
                    "invalid_value", f"Invalid image URL at '{where}.image_url'.", f"{where}.image_url"
                )
            if part.get("detail", "auto") not in ("auto", "low", "high"):
                raise ClientEventError(
                    "invalid_value", f"Invalid value for '{where}.detail'.", f"{where}.detail"
                )
