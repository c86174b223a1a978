#!/usr/bin/env bash
# The main pipeline on the built-in simulator (grows as the toolkit grows).
set -euo pipefail
echo "less demo: the simulator and models are not in this build yet; showing the CLI." >&2
less --help
