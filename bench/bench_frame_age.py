"""Frame age at the question (issue 11; goal <= 100 ms): from the frame forwarder's trigger (the
VAD's voice_activity True: the user starts asking) to the camera frame the Gemini model receives
(a realtimeInput.video at the emulator), and how old that frame is at the question.

Real processes: a 30 fps camera (this process, 320x240 rgb8, each frame's colour encodes its index),
frame_forwarder (triggers only: max_video_fps 0, so every frame the model gets comes from a
trigger), ros_ai_bridge, simple_audio_player, `byc agent` (Gemini provider, official SDK) → the
Gemini emulator (TLS) on a thread here, polled every millisecond for new frames. Each trial: the
trigger, then a 1 s utterance paced like the VAD (100 ms chunks), the reply, the next trial.

Figures per trial:
- trigger → frame at the model: the figure (goal p95 <= 100 ms);
- frame age at the question: trigger time − the frame's capture (publish) time; at 30 fps the
  freshest frame is 0..33 ms old, negative would mean a frame taken after the trigger;
- frame age at the model: the age of the picture when the model gets it.
Baselines in the same run: one raw DDS publish→subscribe of the same camera frame, the JPEG
encode of it in this process (the forwarder's work), one raw WebSocket round trip. The path crosses
2 DDS hops (bench→forwarder, forwarder→bridge), one encode and two WebSocket sends (bridge→agent,
agent→emulator ≈ one round trip): floor = 2 x DDS p50 + encode p50 + WS p50.

    scripts/run.sh python bench/bench_frame_age.py [--trials N]
    unshare -n bash -c 'ip link set lo up; scripts/run.sh python bench/bench_frame_age.py'
"""

from __future__ import annotations

import argparse
import io
import json
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _agent_bench import (  # noqa: E402
    CHUNK_MS,
    VAD_RATE,
    AgentGraph,
    GeminiEmulatorThread,
    agent_graph,
    dds_message_one_way_ms,
    percentile,
    summary,
    table,
    wait_until,
    websocket_round_trip_ms,
)

from by_your_command.emulators import gemini_script as gemini  # noqa: E402

GOAL_P95_MS = 100.0
FPS = 30.0
WIDTH, HEIGHT = 320, 240
WARMUP_TRIALS = 2
FORWARDER = ("max_video_fps:=0.0", "image_transport:=raw")


def colour(index: int) -> tuple[int, int, int]:
    """Frame `index` as a colour that survives JPEG (16 levels a channel, 4096 frames)."""
    return ((index % 16) * 16 + 8, ((index // 16) % 16) * 16 + 8, ((index // 256) % 16) * 16 + 8)


def index_of(jpeg: bytes) -> int:
    from PIL import Image as PilImage

    with PilImage.open(io.BytesIO(jpeg)) as image:
        mean = np.asarray(image.convert("RGB"), dtype=float).reshape(-1, 3).mean(axis=0)
    r, g, b = (int(np.clip(round((v - 8) / 16), 0, 15)) for v in mean)
    return r + 16 * g + 256 * b


def frame_pixels(index: int) -> bytes:
    return np.tile(np.array(colour(index), dtype=np.uint8), (HEIGHT, WIDTH, 1)).tobytes()


class Camera:
    """Publishes frames at FPS on camera/image_raw and remembers when each was published."""

    def __init__(self, graph: AgentGraph) -> None:
        from sensor_msgs.msg import Image

        from by_your_command.nodes._qos import RELIABLE

        self._image = Image
        self._publisher = graph.bench.node.create_publisher(Image, "camera/image_raw", RELIABLE)
        self.published: dict[int, float] = {}  # frame index → time.monotonic() of its publish
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        index, period = 0, 1.0 / FPS
        next_at = time.monotonic()
        while not self._stop.is_set():
            msg = self._image(width=WIDTH, height=HEIGHT, encoding="rgb8", step=WIDTH * 3)
            msg.data = frame_pixels(index % 4096)
            self.published[index % 4096] = time.monotonic()
            self._publisher.publish(msg)
            index += 1
            next_at += period
            self._stop.wait(max(0.0, next_at - time.monotonic()))

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


def speech_like(seconds: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * VAD_RATE)) / VAD_RATE
    return (4000 * np.sin(2 * np.pi * 190 * t) + rng.normal(0, 300, len(t))).astype(np.int16)


def watch(graph: AgentGraph, seen: int, arrivals: list[float], until: float) -> None:
    """Until `until`, note the arrival time of every frame at the model after the first `seen`
    (1 ms polls of the emulator's record)."""
    emulator = graph.emulator
    assert isinstance(emulator, GeminiEmulatorThread)
    while True:
        graph.check()
        while emulator.frames_received() > seen + len(arrivals):
            arrivals.append(time.monotonic())
        if time.monotonic() >= until:
            return
        time.sleep(0.001)


def measure(trials: int) -> dict[str, list[float]]:
    chunk = VAD_RATE * CHUNK_MS // 1000
    to_model: list[float] = []
    age_at_question: list[float] = []
    age_at_model: list[float] = []
    leftovers: list[float] = []  # frames from before the question the model got before its own
    per_question: list[float] = []
    script = gemini.Script(default_reply=gemini.Say("I see."), pace=0.0, ms_per_char=40)
    with agent_graph(script, "frame_age", "gemini", forwarder=FORWARDER) as graph:
        bench, emulator = graph.bench, graph.emulator
        assert isinstance(emulator, GeminiEmulatorThread)
        camera = Camera(graph)
        try:
            wait_until(lambda: len(camera.published) > FPS, 30, "the camera running")
            for trial in range(WARMUP_TRIALS + trials):
                seen = emulator.frames_received()
                metrics_before = len(bench.metrics)
                utterance = bench.new_utterance()
                pcm = speech_like(1.0, trial)
                pieces = [pcm[k : k + chunk] for k in range(0, len(pcm), chunk)]
                arrivals: list[float] = []  # when each frame sent during this question arrived

                trigger = time.monotonic()
                bench.say_activity(True)  # the forwarder's trigger: the user starts asking
                for sequence, piece in enumerate(pieces):
                    bench.voice.publish(bench.chunk(piece, utterance, sequence, sequence == len(pieces) - 1))
                    watch(graph, seen, arrivals, time.monotonic() + CHUNK_MS / 1000)  # paced like the VAD
                bench.say_activity(False)

                def turn_done(before: int = metrics_before) -> Any:
                    graph.check()
                    records = [json.loads(m.msg.data) for m in list(bench.metrics)[before:]]
                    return next((r for r in records if r["record"] == "turn"), None)

                wait_until(turn_done, 30, f"trial {trial}: the reply")
                watch(graph, seen, arrivals, time.monotonic())
                # The question's frame: the newest the camera had at the trigger, or a later one.
                # Frames taken before it were left over from the last question.
                newest = max(at for at in list(camera.published.values()) if at <= trigger)
                captures = [
                    camera.published[index_of(emulator.frame(seen + k))] for k in range(len(arrivals))
                ]
                fresh = [k for k, at in enumerate(captures) if at >= newest]
                assert fresh, f"trial {trial}: no frame taken at or after the question reached the model"
                if trial >= WARMUP_TRIALS:
                    first = fresh[0]
                    to_model.append(1000 * (arrivals[first] - trigger))
                    age_at_question.append(1000 * (trigger - captures[first]))
                    age_at_model.append(1000 * (arrivals[first] - captures[first]))
                    leftovers.append(float(fresh[0]))
                    per_question.append(float(len(arrivals)))
        finally:
            camera.stop()
    return {
        "trigger_to_frame_at_model_ms": to_model,
        "frame_age_at_question_ms": age_at_question,
        "frame_age_at_model_ms": age_at_model,
        "older_frames_sent_first": leftovers,
        "frames_sent_per_question": per_question,
    }


def dds_frame_one_way_ms(trials: int) -> list[float]:
    """A raw DDS publish→subscribe of one camera frame between two participants of this process."""
    from sensor_msgs.msg import Image

    msg = Image(width=WIDTH, height=HEIGHT, encoding="rgb8", step=WIDTH * 3)
    msg.data = frame_pixels(7)
    return dds_message_one_way_ms(trials, msg)


def encode_ms(runs: int) -> list[float]:
    from by_your_command.bridge.frames import FrameForwarderParams
    from by_your_command.bridge.imaging import ImageLimits, RawImage, encode_raw

    params = FrameForwarderParams()
    limits = ImageLimits(params.max_input_pixels, params.max_input_bytes)
    image = RawImage(WIDTH, HEIGHT, "rgb8", WIDTH * 3, frame_pixels(7))
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        encode_raw(image, params.max_width, params.jpeg_quality, limits)
        times.append(1000 * (time.perf_counter() - start))
    return times


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=20)
    args = parser.parse_args()
    figures = measure(args.trials)
    dds = dds_frame_one_way_ms(args.trials * 2)
    encode = encode_ms(args.trials * 2)
    ws = websocket_round_trip_ms(args.trials * 2, speech_like(CHUNK_MS / 1000, 99))
    floor = 2 * percentile(dds, 50) + percentile(encode, 50) + percentile(ws, 50)
    figures |= {
        "baseline_dds_frame_publish_to_subscribe_ms": dds,
        "baseline_jpeg_encode_ms": encode,
        "baseline_websocket_round_trip_ms": ws,
    }
    for name, values in figures.items():
        print(json.dumps({"bench": "frame_age", "figure": name, **summary(values)}))
    to_model = figures["trigger_to_frame_at_model_ms"]
    print(
        json.dumps(
            {
                "bench": "frame_age",
                "figure": "trigger_to_model_vs_transport_floor",
                "p50_ratio_vs_floor": round(percentile(to_model, 50) / floor, 2),
                "floor_ms": round(floor, 2),
                "camera_fps": FPS,
                "goal_p95_ms": GOAL_P95_MS,
                "meets_goal": percentile(to_model, 95) <= GOAL_P95_MS,
            }
        )
    )
    table(
        [
            ("trigger -> frame at the model (the figure)", to_model, f"goal p95 <= {GOAL_P95_MS:g} ms"),
            ("frame age at the question", figures["frame_age_at_question_ms"], f"camera {FPS:g} fps"),
            ("frame age at the model", figures["frame_age_at_model_ms"], "capture -> model"),
            ("older frames sent before the question's", figures["older_frames_sent_first"], "count, not ms"),
            ("frames sent per question", figures["frames_sent_per_question"], "count, not ms"),
            ("baseline: DDS frame publish -> subscribe", dds, "one hop, 320x240 rgb8"),
            ("baseline: JPEG encode", encode, "the forwarder's work"),
            ("baseline: WebSocket round trip", ws, "one round trip"),
            (
                "transport floor (2 DDS + encode + WS)",
                [floor],
                f"p50 = {percentile(to_model, 50) / floor:.1f}x",
            ),
        ]
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
