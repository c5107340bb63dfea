#!/usr/bin/env bash
# Regenerates the bundled vines guide with the project's own pipeline:
# compile -> scribble targets -> unguided SMC traces -> train -> export.
# Usage: bash scripts/train_vines_guide.sh [WORKDIR]   (about 15-25 minutes on 2 cores)
set -euo pipefail
W=${1:-work/vines}
mkdir -p "$W"
ngpmc compile grammars/vines.lsys -o "$W"
ngpmc targets build scribbles -o "$W/scribbles" --count 300 --mirror
ngpmc traces grammars/vines.lsys --targets "$W/scribbles" -n 1000 --particles 600 \
    -o "$W/traces" --workers 2 --seed 0
ngpmc train "$W/traces" -o "$W/model_all_k4.pt" --features all --K 4
ngpmc export "$W/model_all_k4.pt" -o "$W/vines_guide.onnx"
echo "guide: $W/vines_guide.onnx"
