#!/usr/bin/env bash
# The wheel alone runs the tutorial's first step: build it, install it into a fresh venv (torch first),
# then, from an empty folder, `less --help` and `less simulate` on a packaged scene.
#   PYTHON=.venv/bin/python TORCH='torch==2.13.0' bash tools/check_wheel.sh      (or: make wheel-check)
# Needs the `build` package for PYTHON and a package index (or wheel folder) for the dependencies.
set -euo pipefail
PYTHON="${PYTHON:-python3}"
TORCH="${TORCH:-torch==2.13.0}"
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
WORK="$(mktemp -d)"
trap 'rm -rf "$WORK"' EXIT

"$PYTHON" -m build --wheel --outdir "$WORK/dist" "$ROOT" > "$WORK/build.log" || { cat "$WORK/build.log"; exit 1; }
WHEEL="$(ls "$WORK"/dist/*.whl)"
echo "built $(basename "$WHEEL")"
"$PYTHON" -m venv "$WORK/venv"
"$WORK/venv/bin/python" -m pip install -q "$TORCH"
"$WORK/venv/bin/python" -m pip install -q "$WHEEL"
mkdir "$WORK/empty" && cd "$WORK/empty"
PATH="$WORK/venv/bin:$PATH"
less --help > help.txt && grep -q 'simulate' help.txt
lesscli --version
"$WORK/venv/bin/python" -c "import cv2, threadpoolctl; cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)"   # contrib OpenCV
less simulate quick -o scans.npz --set phantoms.random.count=2 --set motion.n_traj=3 --format table
less info scans.npz --format json | "$WORK/venv/bin/python" -c 'import json, sys; r = json.load(sys.stdin)[0]; assert r["scans"] == 2, r'
echo "wheel check passed: $(basename "$WHEEL") installs, 'less --help' and 'less simulate quick' run"
