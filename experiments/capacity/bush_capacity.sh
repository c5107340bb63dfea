#!/bin/bash
# Does a bigger or longer-trained guide help bush? (experiments/notes/bush_capacity.md)
# Trains six variants on every round's traces of a finished `ngpmc learn grammars/bush.lsys`
# run (L below: benchmarks/learn_grammars.py's OUT/bush/learn), exports each and tunes it on
# learn's own validation envelopes (12 targets x 8 runs at N = 10). Run from the repository
# root after `pip install -e .[train]`; results in OUT, a folder per variant.
PY=${PY:-python}
L=${L:-work/learn_grammars/bush/learn}
OUT=${OUT:-work/bush_capacity}
TR=$(ls -d $L/rounds/round_*/traces_0 | paste -sd,)
run() { name=$OUT/$1; shift
  [ -f $name/done ] && return
  mkdir -p $name
  ( time nice $PY -m ngpm_compiler.cli train $TR -o $name/model.pt "$@" ) > $name/train.log 2>&1
  nice $PY -m ngpm_compiler.cli export $name/model.pt -o $name/guide.onnx > $name/export.log 2>&1
  nice $PY -m ngpm_compiler.cli tune $L/bush.lsys $name/guide.onnx -o $name/tuned.onnx --validate env=$L/targets/val_envelopes --targets 12 --repeats 8 --workers 1 --choice-temperatures 1,0.5 --ess none,0.5 > $name/tune.log 2>&1
  touch $name/done
}
run v0_default
run v1_h64 --hidden 64
run v2_h128 --hidden 128
run v3_h128_slow --hidden 128 --lr 0.002 --patience 8 --epochs 100
run v4_K8_h128 --hidden 128 --K 8
run v5_ctx_h128 --hidden 128 --features all+context
