#!/usr/bin/env bash
# Regenerates the bundled circuit guide (runtime/ngpm_runtime/data/vines_circuit_guide.onnx):
# the vines grammar under the paper's circuit likelihood (equation 2; no target: every run
# grows into a blank 50 x 50 canvas from the bottom middle, heading up), in one command:
# `ngpmc learn --likelihood circuit` with a 75-minute budget. The shipped guide is what this
# made on the 2-core machine (2026-11-29, under the circuit potential; 67.3 min): round 0
# from 1305 unguided traces (600 particles), four guided rounds of 661 traces (200
# particles); round 2 validated best (0.724 at N = 10, equal settings) and was tuned to
# T = 1, Tc = 0.7, ESS 0.5 (0.728).
# Its report: docs/results/learn_circuit.md. The plan fits the budget to the measured speed
# of the machine, so a busier machine records fewer traces per round.
# Usage: bash scripts/train_circuit_guide.sh [WORKDIR]   (resumes a stopped run in WORKDIR)
# Then: cp WORKDIR/guide.onnx runtime/ngpm_runtime/data/vines_circuit_guide.onnx and
# re-measure (python benchmarks/circuit.py --guided-n 10,20 --repeats 80 --md docs/results/circuit_guide.md;
# docs/results/README.md, "Circuits").
# (The guide shipped before, 3.3-4.0x: 434 unguided + 249 guided traces, one expert-iteration
# round by hand; experiments/notes/circuit_guide_retrain.md.)
set -euo pipefail
W=${1:-work/circuit}
ngpmc learn grammars/vines.lsys --likelihood circuit -o "$W" --budget 75m --workers 2
echo "guide: $W/guide.onnx"
