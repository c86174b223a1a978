#!/usr/bin/env bash
# The main pipeline on the built-in simulator, a few minutes on a laptop CPU:
# simulate -> subsample -> split -> pretrain -> image fit -> predict -> metrics -> render.
# Data: examples/scenes/quick.toml (16 single-inclusion inserts x 2 orientations, 30 pokes each,
# the fast contact tier, 13 x 64 x 64 label volumes). Outputs go to $DEMO_OUT (default demo-out/).
set -euo pipefail

HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
OUT="${DEMO_OUT:-demo-out}"
SCENE="$HERE/scenes/quick.toml"
DEVICE="${DEMO_DEVICE:-cpu}"
mkdir -p "$OUT"
t0=$SECONDS
step() { printf '\n== [%4ds] %s\n' "$((SECONDS - t0))" "$*" >&2; }

step "1/8 simulate the scans of $SCENE (100 Hz)"
less simulate "$SCENE" -o "$OUT/raw.npz" --jobs 2
step "2/8 subsample 1:50 (pokes)"
less subsample "$OUT/raw.npz" --every 50 -o "$OUT/poke.npz"
step "3/8 split by insert (a quarter of the inserts held out)"
less split "$OUT/poke.npz" --by insert --test 0.25 --seed 0 -o "$OUT/split/" --format table >&2
step "4/8 pretrain the LESS representation (self-supervised force prediction)"
less pretrain "$OUT/split/train.npz" -o "$OUT/rep.pt" --dim 32 --epochs 20 --lr 3e-3 --seed 0 --device "$DEVICE" \
  --format table >&2
step "5/8 fit the 3D image decoder on the label volumes"
less image fit "$OUT/split/train.npz" --rep "$OUT/rep.pt" -o "$OUT/imager.pt" --dim 3 --epochs 80 --lr 1e-2 \
  --set image.patch_px=16 --set image.width=16 --seed 0 --device "$DEVICE" --format table >&2
step "6/8 predict the held-out inserts (whole scans, and 4 prefixes for the figures)"
less image predict "$OUT/imager.pt" "$OUT/split/test.npz" -o "$OUT/pred.npz" --device "$DEVICE" > /dev/null
less image predict "$OUT/imager.pt" "$OUT/split/test.npz" -o "$OUT/pred_steps.npz" --steps 4 --device "$DEVICE" \
  > /dev/null
step "7/8 metrics on the held-out inserts (inclusion class; 'average' = predict the training-mean sphere)"
less metrics "$OUT/pred.npz" --baseline-from "$OUT/split/train.npz" --summary-only --format table \
  | tee "$OUT/metrics.txt"
less metrics "$OUT/pred.npz" --baseline-from "$OUT/split/train.npz" --format jsonl > "$OUT/metrics.jsonl"
echo "(a model that predicts no inclusion scores F1 = 0)"
step "8/8 render truth | prediction | uncertainty, and the image developing over time"
less render "$OUT/pred_steps.npz" -o "$OUT/figures" --format jsonl > "$OUT/figures.jsonl"
printf '\ndemo done in %ds. Figures: %s/figures/ (%d PNG files), e.g.\n' "$((SECONDS - t0))" "$OUT" \
  "$(ls "$OUT/figures" | grep -c '\.png$')"
ls "$OUT"/figures/*.png | head -n 2
echo "Metrics: $OUT/metrics.txt (table), $OUT/metrics.jsonl (per scan)."
