#!/usr/bin/env bash
# Regenerate the speech corpus used by the VAD and clap tests (espeak-ng voices + sox noise).
# Writes corpus/<session>.wav (16 kHz mono int16) and corpus/segments.json: where speech was
# placed in each session, taken from the generation timeline (each utterance trimmed of espeak's
# own leading/trailing silence). Deterministic: espeak-ng is, and sox runs with -R (repeatable noise).
# Usage: make_corpus.sh [output_dir]   (default: the corpus/ directory next to this script)
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
OUT="${1:-$HERE/corpus}"
RATE=16000
GAP=1.5      # silence between utterances (s)
LEAD=1.0     # silence before the first and after the last utterance (s)
for tool in espeak-ng sox soxi; do
  command -v "$tool" >/dev/null || { echo "make_corpus: $tool is required (apt-get install espeak-ng sox)" >&2; exit 1; }
done
WORK="$(mktemp -d)"
trap 'rm -rf "$WORK"' EXIT
mkdir -p "$OUT"

silence() { sox -R -D -n -r "$RATE" -c 1 -b 16 "$1" trim 0 "$2"; }

# session <name> <voice> <noise: none|whitenoise|pinknoise|brownnoise> <noise volume> <sentence>...
session() {
  local name="$1" voice="$2" noise="$3" noise_vol="$4"; shift 4
  local parts=() t="$LEAD" i=0 segments=""
  silence "$WORK/lead.wav" "$LEAD"
  silence "$WORK/gap.wav" "$GAP"
  parts+=("$WORK/lead.wav")
  for sentence in "$@"; do
    espeak-ng -v "$voice" -s 150 -w "$WORK/raw_$i.wav" "$sentence"
    # Trim espeak's silence so the timeline holds speech extents only.
    sox -R -D "$WORK/raw_$i.wav" -r "$RATE" -c 1 -b 16 "$WORK/utt_$i.wav" \
      silence 1 0.01 0.3% reverse silence 1 0.01 0.3% reverse
    local dur; dur="$(soxi -D "$WORK/utt_$i.wav")"
    local end; end="$(awk -v a="$t" -v b="$dur" 'BEGIN { printf "%.3f", a + b }')"
    segments+="${segments:+, }{\"start\": $t, \"end\": $end, \"text\": \"$sentence\"}"
    t="$(awk -v a="$end" -v b="$GAP" 'BEGIN { printf "%.3f", a + b }')"
    parts+=("$WORK/utt_$i.wav")
    if [ $((i + 1)) -lt $# ]; then parts+=("$WORK/gap.wav"); fi
    i=$((i + 1))
  done
  parts+=("$WORK/lead.wav")
  sox -R -D "${parts[@]}" "$WORK/clean_$name.wav"
  if [ "$noise" = none ]; then
    cp "$WORK/clean_$name.wav" "$OUT/$name.wav"
  else
    local total; total="$(soxi -D "$WORK/clean_$name.wav")"
    sox -R -D -n -r "$RATE" -c 1 -b 16 "$WORK/noise.wav" synth "$total" "$noise" vol "$noise_vol"
    sox -R -D -m -v 1 "$WORK/clean_$name.wav" -v 1 "$WORK/noise.wav" "$OUT/$name.wav"
  fi
  SESSIONS+="${SESSIONS:+,
  }\"$name\": {\"voice\": \"$voice\", \"noise\": \"$noise\", \"noise_volume\": $noise_vol, \"segments\": [$segments]}"
}

SESSIONS=""
session clean_en_us en-us none 0 \
  "Hello robot, what do you see?" "Turn left and look at the door." "Go to sleep." \
  "Pick up the red block please."
session white_noise_en_gb en-gb whitenoise 0.03 \
  "Good morning, can you hear me?" "Move forward two steps." "Stop."
session pink_noise_en_us_f3 en-us+f3 pinknoise 0.05 \
  "Hey robot, wake up." "What colour is the cup on the table?" "Thank you, that is all."
printf '{"sample_rate": %d, "sessions": {\n  %s\n}}\n' "$RATE" "$SESSIONS" > "$OUT/segments.json"
echo "make_corpus: wrote $(ls "$OUT" | wc -l) files to $OUT ($(du -sh "$OUT" | cut -f1))"
