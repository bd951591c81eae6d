"""Fit the offline recognizer's reranking weights (local_speech/rescoring.py, RerankWeights) on tuning
voices, and show what the accept rules make of them.

Tuning voices are espeak-ng voices, speeds and pitches that the benchmark never uses
(bench_offline_recognition.py holds those out): every spoken form of the vocabulary said by two of
them, each chat line by three, clean and with white and pink noise at 15 dB, and each chat line in
--chat-draws more draws of both noises (a chat line taken is rare); with --room RT60 [--drr dB],
also in a reverberant room (bench_offline_recognition.in_room), quiet and in pink noise (the fits
below then take the room's records too). Every utterance is decoded once
(OfflineRecognizer.evidence, plus pocketsphinx's filler pass) and the records saved as JSON
(--records: read them instead of decoding again). Then:

- a conditional logit fits one weight per piece of evidence so that the right candidate of each
  command utterance gets the highest score (candidates: Moonshine's leading meanings that aligned;
  utterances whose right meaning is not among them are left out of the fit);
- the tuning voices are split in two halves, and weights fitted on one half are tested on the
  other (both ways): the fit is worth shipping only if it gains there too;
- every variant is scored by the shipped accept rules (OfflineRecognizer.decide): exact commands,
  chat taken as a command, commands taken as another command; and the ceiling (the reranked best
  is the right meaning, no rejection).

usage: scripts/run.sh python bench/tune_offline_reranking.py [--records FILE] [--margin 1.0] [--chat-draws 3]
       [--room 0.5 --drr 0]
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from bench_offline_recognition import (
    CHAT,
    COMMAND_KINDS,
    add_room_arguments,
    in_room,
    noise_condition,
    room_condition,
    room_of,
    synthesize,
    with_noise,
)
from scipy.optimize import minimize

from by_your_command.audio.pcm import Int16Array
from by_your_command.local_speech.acceptance import Acceptance, AcceptLimits
from by_your_command.local_speech.moonshine import FormScore
from by_your_command.local_speech.recognizer import Evidence, OfflineRecognizer
from by_your_command.local_speech.rescoring import (
    Alignment,
    Candidate,
    RerankWeights,
    evidence_vector,
    rescore,
)

# (voice, words per minute, pitch): none of them is a benchmark voice
TUNING_VOICES = (
    ("en-gb-scotland+m3", 150, 50), ("en-gb-x-gbclan+f2", 160, 60), ("en-us+m5", 140, 40),
    ("en-gb-x-gbcwmd+f4", 170, 55), ("en-us+klatt", 155, 45), ("en-gb+f1", 145, 65), ("en-us+m2", 175, 35),
    ("en-gb-scotland+f5", 165, 50), ("en-us+m1", 150, 45), ("en-gb+m4", 160, 40),
)  # fmt: skip
SNR_DB = 15.0
NOISES = ("white", "pink")
FEATURES = tuple(field.name for field in dataclasses.fields(RerankWeights))
# log probability + 0.04 x alignment: the score before the fit
PREVIOUS = RerankWeights(**{**dict.fromkeys(FEATURES, 0.0), "logprob": 1.0, "alignment": 0.04})


@dataclasses.dataclass(frozen=True)
class Record:
    voice: str
    condition: str
    expected: tuple[str, str] | None  # (kind, canonical); None for chat
    evidence: Evidence
    filler: str  # what pocketsphinx's filler pass heard


def decode_corpus(
    recognizer: OfflineRecognizer, chat_draws: int, room: tuple[float, float] | None = None
) -> list[Record]:
    """Every utterance clean and in each noise, and in `room` (RT60 s, direct-to-reverberant dB)
    quiet and in pink noise; then each chat line again in `chat_draws` more draws of each noise
    (a chat line taken is rare: one draw says little)."""
    meanings: dict[tuple[str, str], list[str]] = {}
    for form in (form for form in recognizer.forms if not form.polite):
        meanings.setdefault((form.kind.value, form.canonical), []).append(form.words)
    said: list[tuple[str, tuple[str, str] | None]] = [
        (words, meaning) for meaning, forms in sorted(meanings.items()) for words in forms
    ]
    records = []
    chat_said: list[tuple[int, str, Int16Array]] = []  # (turn, voice, speech)

    def decode(voice: str, condition: str, expected: tuple[str, str] | None, samples: Int16Array) -> None:
        evidence = recognizer.evidence(samples)
        records.append(Record(voice, condition, expected, evidence, recognizer.filler_heard(samples)))
        print(f"decoded {len(records)} utterances", end="\r", flush=True)

    turn = 0
    for text, expected in [*said, *((line, None) for line in CHAT)]:
        for _ in range(2 if expected else 3):
            voice, speed, pitch = TUNING_VOICES[turn % len(TUNING_VOICES)]
            turn += 1
            speech = synthesize(text, voice, speed, pitch)
            decode(voice, "clean", expected, speech)
            for noise in NOISES:
                noisy = with_noise(speech, SNR_DB, turn, noise)
                decode(voice, noise_condition(noise, SNR_DB), expected, noisy)
            if room is not None:
                reverberant, name = in_room(speech, *room, turn), room_condition(*room)
                decode(voice, name, expected, reverberant)
                noisy = with_noise(reverberant, SNR_DB, turn, "pink")
                decode(voice, f"{name} {noise_condition('pink', SNR_DB)}", expected, noisy)
            if expected is None:
                chat_said.append((turn, voice, speech))
    for draw in range(1, chat_draws + 1):
        for turn, voice, speech in chat_said:
            for noise in NOISES:
                samples = with_noise(speech, SNR_DB, 10000 * draw + turn - 1, noise)
                decode(voice, f"{noise_condition(noise, SNR_DB)} draw{draw}", None, samples)
    return records


def from_json(data: dict[str, Any]) -> Record:
    evidence = data["evidence"]
    candidates = [
        Candidate(
            FormScore(**c["score"]),
            None if c["alignment"] is None else Alignment(**c["alignment"]),
            int(c["words"]),
            bool(c["grammar_agrees"]),
        )
        for c in evidence["candidates"]
    ]
    return Record(
        data["voice"],
        data["condition"],
        None if data["expected"] is None else (data["expected"][0], data["expected"][1]),
        Evidence(
            float(evidence["snr_db"]),
            [FormScore(**f) for f in evidence["forms"]],
            str(evidence["free_text"]),
            str(evidence["grammar_text"]),
            candidates,
            float(evidence["fall_ms"]),
        ),
        str(data["filler"]),
    )


def fit(
    records: list[Record], meaning_of: Callable[[FormScore], tuple[str, str]], l2: float = 1.0
) -> RerankWeights:
    """Conditional logit: the weights that make each command's right candidate most likely. `l2`
    (on weights in standard units) keeps them small: unpenalised, the evidence separates most
    utterances outright and the weights grow without changing the ranking, which makes a fixed
    margin mean less and less."""
    groups = []
    for record in records:
        aligned = [(c, c.alignment) for c in record.evidence.candidates if c.alignment is not None]
        right = [i for i, (c, _) in enumerate(aligned) if meaning_of(c.score) == record.expected]
        if record.expected is not None and right and len(aligned) > 1:
            groups.append((np.array([evidence_vector(c, alignment) for c, alignment in aligned]), right[0]))
    if not groups:
        raise SystemExit("no command utterance with its right meaning among two or more candidates")
    scale = np.vstack([x for x, _ in groups]).std(axis=0) + 1e-9  # fit in standard units
    scaled = [(x / scale, right) for x, right in groups]

    def loss(w: np.ndarray) -> tuple[float, np.ndarray]:
        total, grad = l2 * float(w @ w), 2 * l2 * w
        for x, right in scaled:
            z = x @ w
            p = np.exp(z - z.max())
            p /= p.sum()
            total -= float(np.log(max(p[right], 1e-300)))
            grad = grad - (x[right] - p @ x)
        return total, grad

    result = minimize(loss, np.zeros(len(FEATURES)), jac=True, method="L-BFGS-B")
    weights = result.x / scale
    return RerankWeights(
        **{name: float(f"{value:.2g}") for name, value in zip(FEATURES, weights, strict=True)}
    )


@dataclasses.dataclass
class Score:
    commands: int = 0
    exact: int = 0
    ceiling: int = 0
    chat_taken: int = 0
    wrong: int = 0

    def row(self) -> str:
        chat = f"chat->cmd {self.chat_taken:3d}"
        if not self.commands:  # the further noise draws hold chat lines only
            return f"{'':30}{chat}"
        exact, ceiling = (100.0 * n / self.commands for n in (self.exact, self.ceiling))
        return f"{exact:6.1f} %  ceiling {ceiling:5.1f} %  {chat}  wrong {self.wrong:3d}"


def evaluate(
    recognizer: OfflineRecognizer, records: list[Record], acceptance: Acceptance
) -> dict[str, Score]:
    scores: dict[str, Score] = {}
    for record in records:
        score = scores.setdefault(record.condition, Score())
        chosen = recognizer.decide(record.evidence, acceptance, functools.partial(str, record.filler))
        taken = None if chosen is None else recognizer.forms[chosen.index]
        if record.expected is None:
            score.chat_taken += taken is not None and taken.kind in COMMAND_KINDS
            continue
        score.commands += 1
        meaning = None if taken is None else (taken.kind.value, taken.canonical)
        score.exact += meaning == record.expected
        score.wrong += taken is not None and meaning != record.expected and taken.kind in COMMAND_KINDS
        reranked = rescore(record.evidence.candidates, acceptance.rerank)
        score.ceiling += bool(reranked) and meaning_key(recognizer, reranked[0].score) == record.expected
    return scores


def meaning_key(recognizer: OfflineRecognizer, score: FormScore) -> tuple[str, str]:
    form = recognizer.forms[score.index]
    return form.kind.value, form.canonical


def with_rerank(weights: RerankWeights, margin: float) -> Acceptance:
    shipped = Acceptance()
    return dataclasses.replace(
        shipped,
        rerank=weights,
        clean=dataclasses.replace(shipped.clean, alignment_path_min_margin=margin),
        noisy=dataclasses.replace(shipped.noisy, alignment_path_min_margin=margin),
    )


def report(name: str, scores: dict[str, Score]) -> None:
    for condition in sorted(scores):
        print(f"  {name:<46}{condition:<20}{scores[condition].row()}")
        record = {"bench": "offline_reranking", "variant": name, "condition": condition}
        print(json.dumps({**record, **dataclasses.asdict(scores[condition])}), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--records", type=Path, help="JSON records: read if present, else written")
    parser.add_argument(
        "--margin", type=float, default=AcceptLimits().alignment_path_min_margin, help="alignment path margin"
    )
    parser.add_argument(
        "--chat-draws", type=int, default=3, help="more noise draws of each chat line (when decoding)"
    )
    add_room_arguments(parser)  # when decoding: also in this room
    args = parser.parse_args()
    room = room_of(parser, args)
    recognizer = OfflineRecognizer()
    if recognizer.search.value != "moonshine":
        raise SystemExit("the Moonshine model is not installed: nothing to tune")
    if args.records is not None and args.records.exists():
        records = [from_json(item) for item in json.loads(args.records.read_text())]
    else:
        records = decode_corpus(recognizer, args.chat_draws, room)
        if args.records is not None:
            args.records.write_text(json.dumps([dataclasses.asdict(record) for record in records]))
    print(f"{len(records)} utterances, {sum(r.expected is not None for r in records)} of them commands")

    meaning_of = functools.partial(meaning_key, recognizer)
    fitted = fit(records, meaning_of)
    print(f"fitted on all tuning voices: {fitted}")
    print(f"\n{'variant (shipped accept rules)':<48}{'condition':<20}exact commands")
    report("shipped weights", evaluate(recognizer, records, Acceptance()))
    report("previous score, margin 2", evaluate(recognizer, records, with_rerank(PREVIOUS, 2.0)))
    report(
        f"fitted on all, margin {args.margin:g}",
        evaluate(recognizer, records, with_rerank(fitted, args.margin)),
    )
    voices = [voice for voice, _, _ in TUNING_VOICES]
    halves = (set(voices[0::2]), set(voices[1::2]))
    for train, test in (halves, halves[::-1]):
        fitted_half = fit([r for r in records if r.voice in train], meaning_of)
        tested = [r for r in records if r.voice in test]
        print(f"\nfitted on {sorted(train)}: {fitted_half}")
        report(
            "  other half: previous score, margin 2",
            evaluate(recognizer, tested, with_rerank(PREVIOUS, 2.0)),
        )
        report(
            f"  other half: fitted, margin {args.margin:g}",
            evaluate(recognizer, tested, with_rerank(fitted_half, args.margin)),
        )


if __name__ == "__main__":
    main()
