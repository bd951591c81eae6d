#!/usr/bin/env bash
# Build the demo's speech file (demo_speech.wav next to this script): one person talking to the
# robot for ~28 s, 16 kHz mono int16, with pauses long enough for the robot's spoken answers
# (the default echo mode `gate` closes the microphone while the robot speaks).
#
#   look up · pan left · what time is it · go to sleep · turn right (asleep: must be ignored)
#   · wake up · stop
#
# Voices: en-us+m7 and en-gb-x-rp, not the corpus voices (en-us, en-us+f3, en-gb) that the offline
# recognizer is tuned and measured on. A faint pink-noise bed (about -50 dBFS) runs under
# everything, as in a quiet room. Deterministic: espeak-ng is, and sox runs with -R (repeatable
# noise), so the same tools write the same bytes.
# Usage: make_demo_speech.sh [output.wav]   (default: demo_speech.wav next to this script)
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
OUT="${1:-$HERE/demo_speech.wav}"
RATE=16000
VOICE_A="en-us+m7"
VOICE_B="en-gb-x-rp"
NOISE_VOLUME=0.006
for tool in espeak-ng sox soxi; do
  command -v "$tool" >/dev/null || { echo "make_demo_speech: $tool is required (apt-get install espeak-ng sox)" >&2; exit 1; }
done
WORK="$(mktemp -d)"
trap 'rm -rf "$WORK"' EXIT
PARTS=()
N=0

silence() {  # silence <seconds>
  sox -R -D -n -r "$RATE" -c 1 -b 16 "$WORK/part_$N.wav" trim 0 "$1"
  PARTS+=("$WORK/part_$N.wav"); N=$((N + 1))
}

say() {  # say <voice> <text>: the utterance, trimmed of espeak's own leading/trailing silence
  espeak-ng -v "$1" -s 150 -w "$WORK/raw_$N.wav" "$2"
  sox -R -D "$WORK/raw_$N.wav" -r "$RATE" -c 1 -b 16 "$WORK/part_$N.wav" \
    silence 1 0.01 0.3% reverse silence 1 0.01 0.3% reverse
  PARTS+=("$WORK/part_$N.wav"); N=$((N + 1))
}

# Pauses after each line: the robot's answer (~1-2 s) plus its latency must end before the next.
silence 2.0
say "$VOICE_A" "Look up.";          silence 3.0
say "$VOICE_B" "Pan left.";         silence 3.0
say "$VOICE_A" "What time is it?";  silence 3.8
say "$VOICE_B" "Go to sleep.";      silence 3.0
say "$VOICE_A" "Turn right.";       silence 2.2
say "$VOICE_B" "Wake up.";          silence 3.0
say "$VOICE_A" "Stop.";             silence 2.5

sox -R -D "${PARTS[@]}" "$WORK/clean.wav"
TOTAL="$(soxi -D "$WORK/clean.wav")"
sox -R -D -n -r "$RATE" -c 1 -b 16 "$WORK/noise.wav" synth "$TOTAL" pinknoise vol "$NOISE_VOLUME"
mkdir -p "$(dirname "$OUT")"
sox -R -D -m -v 1 "$WORK/clean.wav" -v 1 "$WORK/noise.wav" -b 16 "$OUT"
echo "make_demo_speech: wrote $OUT ($(soxi -d "$OUT"), $(du -k "$OUT" | cut -f1) KB)"
