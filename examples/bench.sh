#!/usr/bin/env bash
# Benchmarks: each prints ratios against a baseline measured in the same run.
set -euo pipefail
echo "less bench: no benchmarks in this build yet." >&2
