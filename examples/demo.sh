#!/usr/bin/env bash
# The main pipeline on the built-in simulator, a few minutes on a laptop CPU:
# simulate -> subsample -> split -> pretrain -> image fit -> predict -> metrics -> render.
# Training data: examples/scenes/quick.toml, 120 randomised single-inclusion inserts (one orientation, 30
# pokes each, the fast contact tier, 13 x 64 x 64 label volumes), a validation share split off by insert.
# Evaluation: 16 catalogue inserts x 2 orientations simulated with the same scene, never seen in training.
# LESS is reported next to the classical force-map imager and the average-prediction baseline.
# Outputs go to $DEMO_OUT (default demo-out/); the LESS imager ends at $DEMO_OUT/imager.pt.
#
# Every setting below can be overridden from the environment (arguments split at spaces), e.g. a tiny run:
#   DEMO_OUT=/tmp/demo_small TRAIN_SET_ARGS="--set phantoms.random.count=6" \
#   PRETRAIN_ARGS="--dim 8 --epochs 1 --set ssl.k_input=4 --set ssl.k_query=4" \
#   FIT_ARGS="--epochs 1 --set image.patch_px=16 --set image.width=8" bash examples/demo.sh
# Another sensor: DEMO_SCENE=examples/scenes/pad4x4.toml (a 4 x 4 pad) or examples/scenes/probe.toml (one taxel).
set -euo pipefail

: "${LESS_MODEL:=less-taxel}"
: "${PRETRAIN_ARGS:=--dim 16 --epochs 8 --lr 3e-3 --batch-size 4 --set ssl.k_input=8 --set ssl.k_query=8}"
: "${FIT_ARGS:=--epochs 40 --lr 1e-2 --batch-size 4 --set image.patch_px=16 --set image.width=16 --set loss.alpha_power=0.5}"
: "${TRAIN_SET_ARGS:=}"
HELDOUT_NAMES='["St8C5","St8C9","St8D13","St10C9","St10D5","St10D13","St12C5","St12C13","St12D9","St14C5","St14D9","St14D13","St16C9","St16C13","St16D5","St16D9"]'

HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
OUT="${DEMO_OUT:-demo-out}"
SCENE="${DEMO_SCENE:-$HERE/scenes/quick.toml}"
DEVICE="${DEMO_DEVICE:-cpu}"
read -r -a TRAIN_SET <<< "$TRAIN_SET_ARGS"
read -r -a PRETRAIN <<< "$PRETRAIN_ARGS"
read -r -a FIT <<< "$FIT_ARGS"
# orientation 0 of every other held-out insert (scans are insert-major, two orientations each)
FIGURE_SCANS=(--scan 0 --scan 4 --scan 8 --scan 12 --scan 16 --scan 20 --scan 24 --scan 28)
mkdir -p "$OUT"
t0=$SECONDS
step() { printf '\n== [%4ds] %s\n' "$((SECONDS - t0))" "$*" >&2; }

step "1/9 simulate the randomised training family of $SCENE (100 Hz), subsample 1:50 (pokes)"
less simulate "$SCENE" -o "$OUT/train_raw.npz" --jobs 2 ${TRAIN_SET[@]+"${TRAIN_SET[@]}"} --format table >&2
less subsample "$OUT/train_raw.npz" --every 50 -o "$OUT/train.npz"
step "2/9 split off a validation share by insert (split/train.npz: training, split/test.npz: validation)"
less split "$OUT/train.npz" --by insert --test 0.15 --seed 0 -o "$OUT/split/" --format table >&2
step "3/9 simulate the held-out evaluation set: 16 catalogue inserts x 2 orientations, the same scene"
less simulate "$SCENE" -o "$OUT/heldout_raw.npz" --jobs 2 --set phantoms.set=single \
  --set "phantoms.names=$HELDOUT_NAMES" --set 'phantoms.orientations=[0,4]' --format table >&2
less subsample "$OUT/heldout_raw.npz" --every 50 -o "$OUT/heldout.npz"
step "4/9 pretrain the LESS representation ($LESS_MODEL; self-supervised force prediction)"
less pretrain "$OUT/split/train.npz" --val "$OUT/split/test.npz" -o "$OUT/rep.pt" --model "$LESS_MODEL" \
  "${PRETRAIN[@]}" --seed 0 --device "$DEVICE" --format table >&2
step "5/9 fit the LESS 3D image decoder on the label volumes"
less image fit "$OUT/split/train.npz" --val "$OUT/split/test.npz" --rep "$OUT/rep.pt" -o "$OUT/imager.pt" \
  --dim 3 "${FIT[@]}" --seed 0 --device "$DEVICE" --format table >&2
step "6/9 calibrate the classical force-map imager on the same training scans"
less image fit "$OUT/split/train.npz" --model forcemap -o "$OUT/forcemap.pt" --format table >&2
step "7/9 image the held-out set with both (whole scans, and 4 prefixes of LESS for the figures)"
less image predict "$OUT/imager.pt" "$OUT/heldout.npz" -o "$OUT/pred_less.npz" --device "$DEVICE" > /dev/null
less image predict "$OUT/forcemap.pt" "$OUT/heldout.npz" -o "$OUT/pred_forcemap.npz" > /dev/null
less image predict "$OUT/imager.pt" "$OUT/heldout.npz" -o "$OUT/pred_steps.npz" --steps 4 --device "$DEVICE" \
  > /dev/null
step "8/9 metrics on the held-out set (inclusion class; 'average' = predict the training-mean sphere)"
PREDS=("$OUT/pred_less.npz" "$OUT/pred_forcemap.npz")
less metrics "${PREDS[@]}" --baseline-from "$OUT/split/train.npz" --group-by model --summary-only --format table \
  > "$OUT/metrics.txt"
less metrics "${PREDS[@]}" --baseline-from "$OUT/split/train.npz" --group-by model --summary-only \
  --show f1_micro_3d,f1_3d,com_error_mm_3d,diameter_error_mm_3d,f1_micro_2d > "$OUT/headline.txt"
less metrics "${PREDS[@]}" --baseline-from "$OUT/split/train.npz" --group-by model --format jsonl \
  > "$OUT/metrics.jsonl"
step "9/9 render truth | LESS | classical, LESS uncertainty and the image over time, for 8 held-out scans"
mkdir -p "$OUT/figures"
less render "${PREDS[@]}" -o "$OUT/figures/compare" "${FIGURE_SCANS[@]}" --format jsonl > "$OUT/figures_compare.jsonl"
less render "$OUT/pred_steps.npz" -o "$OUT/figures/less" "${FIGURE_SCANS[@]}" --format jsonl > "$OUT/figures.jsonl"

printf '\ndemo done in %ds. Held-out catalogue inserts, never seen in training:\n\n' "$((SECONDS - t0))"
cat "$OUT/headline.txt"
echo "(a model that predicts no inclusion scores F1 = 0; every metric, 2D and 3D: $OUT/metrics.txt)"
printf '\nImager: %s/imager.pt (any scan simulated with %s'"'"'s settings: less image predict %s/imager.pt SCANS.npz -o pred.npz)\n' \
  "$OUT" "$(basename "$SCENE")" "$OUT"
printf 'Figures: %s/figures/compare/ (truth | LESS | classical), %s/figures/less/ (%d PNG files), e.g.\n' "$OUT" "$OUT" \
  "$(find "$OUT/figures" -name '*.png' | wc -l)"
ls "$OUT"/figures/compare/*.png | head -n 2
echo "Metrics: $OUT/headline.txt (the table above), $OUT/metrics.txt (every metric), $OUT/metrics.jsonl (per scan and per model)."
echo "What any of these files holds: less info $OUT/imager.pt (or heldout.npz, pred_less.npz, ...)."
