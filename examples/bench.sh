#!/usr/bin/env bash
# Benchmarks: each prints ratios against a baseline measured in the same run.
set -euo pipefail
less bench metrics --quick
less bench train --quick --threads 1
less bench mri --quick
less bench sim --quick
less bench pose --quick
less bench stream --quick --dim 2
less bench guide --quick
less bench imaging --quick --threads 1
less bench tradeoff --quick --knob receptive_field --values receptive_field=5 --family 12 --heldout 4 --multiple 2 \
  --image-epochs 5 --threads 1
