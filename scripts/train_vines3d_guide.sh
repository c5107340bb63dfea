#!/usr/bin/env bash
# Regenerates the bundled 3D guide (runtime/ngpm_runtime/data/vines3d_guide.onnx): the
# 3D vines (grammars/vines3d.lsys) learned in one command, `ngpmc learn` with a 45-minute
# budget: 3D training and validation targets (blobs3d, extruded), round 0 from unguided
# SMC traces (600 particles), expert-iteration rounds with guided teachers, tuning. The
# held-out `revolved` set is never used (python benchmarks/eval3d.py scores the guide on
# it; docs/results/README.md, "3D"). The plan fits the budget to the measured speed of the
# machine, so a busier machine records fewer traces per round. The bundled file is the
# 45-minute run of 2026-11-25 (docs/results/3d/learn_vines3d.md) re-tuned with the tune grid
# learn's tune stage has since run (choice temperatures down to 0.05; tune_vines3d.md there).
# Usage: bash scripts/train_vines3d_guide.sh [WORKDIR]   (resumes a stopped run in WORKDIR)
# Then: cp WORKDIR/guide.onnx runtime/ngpm_runtime/data/vines3d_guide.onnx
set -euo pipefail
W=${1:-work/vines3d}
ngpmc learn grammars/vines3d.lsys -o "$W" --budget 45m --workers 2
echo "guide: $W/guide.onnx"
