"""What `byc demo` runs: which profile and agent, where the sound comes from and goes to.

Pure decisions (no processes, no printing): the provider picks the profile; a cloud provider needs
its key in the environment; the offline demo always plays a speech file into a WAV sink, a cloud
demo uses the microphone and speaker when both exist and the bundled file otherwise.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

from by_your_command.demo import bundled_speech

REPLY_WAV = "robot_said.wav"
GRAPH_LOG = "graph.log"


@dataclass(frozen=True)
class Provider:
    name: str
    profile: str  # the graph profile (graph/profiles.py) the demo starts
    label: str
    key_envs: tuple[str, ...] = ()  # any one of these holds the API key


PROVIDERS: dict[str, Provider] = {
    p.name: p
    for p in (
        Provider("offline", "offline", "the offline agent (no network, no API key)"),
        Provider("openai", "oai_realtime", "an OpenAI Realtime agent", ("OPENAI_API_KEY",)),
        Provider("gemini", "gemini_live", "a Gemini Live agent", ("GEMINI_API_KEY", "GOOGLE_API_KEY")),
        Provider("gpt-live", "gpt_live", "an OpenAI GPT-Live agent (full duplex)", ("OPENAI_API_KEY",)),
    )
}


def default_out_dir(environ: Mapping[str, str] | None = None) -> Path:
    """$XDG_STATE_HOME/by_your_command/demo (~/.local/state/... when unset): outside any checkout."""
    env = os.environ if environ is None else environ
    state = env.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(state) / "by_your_command" / "demo"


class DemoSetupError(Exception):
    """The demo cannot start as asked (a missing key, a missing file): exit status 2."""


@dataclass(frozen=True)
class DemoPlan:
    provider: Provider
    audio_source: str  # a graph option: "mic" or "file:<path>"
    audio_sink: str  # a graph option: "device" or "wav:<path>"
    out_dir: Path

    @property
    def speech(self) -> Path | None:
        return Path(self.audio_source[5:]) if self.audio_source.startswith("file:") else None

    @property
    def reply_wav(self) -> Path | None:
        return Path(self.audio_sink[4:]) if self.audio_sink.startswith("wav:") else None

    @property
    def ends_by_itself(self) -> bool:
        """A file source ends; a microphone runs until Ctrl-C."""
        return self.speech is not None

    @property
    def graph_log(self) -> Path:
        return self.out_dir / GRAPH_LOG


def missing_key(provider: Provider, environ: Mapping[str, str]) -> str | None:
    """What is missing to run `provider`, said plainly; None when nothing is."""
    if not provider.key_envs or any(environ.get(name) for name in provider.key_envs):
        return None
    names = " or ".join(provider.key_envs)
    return (
        f"--provider {provider.name} needs an API key: set {names} in the environment "
        f"(export it in your shell, never in a file). Without a key, run the offline demo: make demo"
    )


def make_plan(
    provider_name: str,
    input_wav: Path | None,
    out_dir: Path | None,
    environ: Mapping[str, str],
    have_mic_and_speaker: Callable[[], bool],
) -> DemoPlan:
    """The demo to run; DemoSetupError says what is missing."""
    provider = PROVIDERS[provider_name]
    problem = missing_key(provider, environ)
    if problem:
        raise DemoSetupError(problem)
    out_dir = (out_dir or default_out_dir(environ)).expanduser().resolve()
    if provider.key_envs and input_wav is None and have_mic_and_speaker():
        return DemoPlan(provider, "mic", "device", out_dir)
    if input_wav is None:
        try:
            speech = bundled_speech()
        except FileNotFoundError as error:
            raise DemoSetupError(str(error)) from None
    else:
        speech = input_wav.expanduser().resolve()
        if not speech.is_file():
            raise DemoSetupError(f"no such speech file {speech}")
    return DemoPlan(provider, f"file:{speech}", f"wav:{out_dir / REPLY_WAV}", out_dir)


def mic_and_speaker_present() -> bool:
    """Both a capture and a playback device (PortAudio); False when PortAudio itself is missing."""
    try:
        from by_your_command.audio.devices import query_devices

        devices, _, _ = query_devices()
    except Exception:  # no sounddevice, no libportaudio, no sound server: all mean "none"
        return False
    return any(d.has("input") for d in devices) and any(d.has("output") for d in devices)
