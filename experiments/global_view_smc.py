"""Guided SMC with a guide that reads a global view of the target (experiments/notes/
own_samples.md), before the runtime computes such a group.

    python experiments/global_view_smc.py GRAMMAR GUIDE DIR[,DIR...] [--view] \
        --settings 1:1:0.5 --runs 16

GUIDE: `ngpmc export` of a model trained on `experiments/global_view.py`'s traces (--view:
its context group is 17 + 36 columns wide, the last 36 the target's coarsest pyramid
level), or of one trained on the plain traces (without --view: the baseline on the same
code path). The compiled deriver is switched off (smc.USE_COMPILED) and, with --view,
FeatureMaker.rows_from fills the 36 columns after its kernel (the Python path only), so
both guides run the same Python deriver. Prints the mean over targets of the median
similarity at N = 10 per setting, as experiments/guide_settings.py does.
"""

from __future__ import annotations

import argparse

import numpy as np
from ngpm_runtime.image import features as feats
from ngpm_runtime.image.raster import N_LEVELS
from ngpm_runtime.inference import smc

VIEW = 36  # 6 x 6: the coarsest level of a 50 x 50 target


def add_view() -> None:
    """Widen the context group by VIEW columns and fill them with the target's coarsest
    pyramid level (row-major, image axes)."""
    feats.N_CONTEXT = 2 + len(feats.RAY_ANGLES) * len(feats.RAY_DIST) + VIEW
    plain = feats.FeatureMaker.rows_from

    def rows_from(self, canvas, idx, turtle, depth, extra, n_extra):  # type: ignore[no-untyped-def]
        out = plain(self, canvas, idx, turtle, depth, extra, n_extra)
        if self.context:
            view = (
                np.zeros(VIEW, np.float32)
                if self.target_levels is None
                else self.target_levels[N_LEVELS - 1].ravel()[:VIEW]
            )
            start = feats.N_LOCAL_BASE + n_extra + 2 * feats.N_WINDOW + feats.N_CONTEXT - VIEW
            cols = start[:, None] + np.arange(VIEW)[None, :]
            out[np.arange(len(out))[:, None], cols] = view[None, :]
        return out

    feats.FeatureMaker.rows_from = rows_from  # type: ignore[method-assign]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("grammar")
    ap.add_argument("guide")
    ap.add_argument("targets")
    ap.add_argument("--view", action="store_true")
    ap.add_argument("--settings", default="1:1:0.5")
    ap.add_argument("--runs", type=int, default=16)
    a = ap.parse_args()
    smc.USE_COMPILED = False
    if a.view:
        add_view()
    from guide_settings import load_sets, parse_setting, score  # experiments/, beside this
    from ngpm_runtime.inference.guide import Guide

    from ngpm_compiler.language.compile import load_grammar

    program = load_grammar(a.grammar)
    targets = load_sets(a.targets, program)
    for text in a.settings.split(","):
        guide = Guide.load(a.guide, program, settings=parse_setting(text))
        sim = score(program, targets, guide, 10, a.runs)
        print(f"N=10 {text} view={a.view}: {sim:.3f} ({len(targets)} targets)")


if __name__ == "__main__":
    main()
