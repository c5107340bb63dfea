"""How well does a forward sample fill its own envelope? (experiments/notes/own_samples.md)

    python experiments/own_ceiling.py GRAMMAR [--samples 200] [--seed 777]

Forward samples of the grammar (trace_jobs.own_sample: the envelopes `ngpmc traces
--own-samples` records into), each scored against its own envelope with the shape
similarity of docs/results: what a sampler that found the very sample behind an envelope
would score there. Prints the mean and the 10th, 50th and 90th percentiles.
"""

from __future__ import annotations

import argparse

import numpy as np
from ngpm_runtime.image.raster import rasterize
from ngpm_runtime.inference.likelihood import similarity

from ngpm_compiler.language.compile import load_grammar
from ngpm_compiler.learning.trace_jobs import job_spec, own_sample


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("grammar")
    ap.add_argument("--samples", type=int, default=200)
    ap.add_argument("--seed", type=int, default=777)
    a = ap.parse_args()
    program = load_grammar(a.grammar)
    scores = []
    for job in range(a.samples):
        found = own_sample(program, job_spec(a.seed, job, 1)[1], 50)
        if found is None:
            continue
        sample, target = found
        img = rasterize(list(sample.primitives), program.viewport, 50, 50)
        scores.append(similarity(img > 0, target.mask))
    q = np.percentile(scores, [10, 50, 90])
    print(
        f"{a.grammar}: {len(scores)} samples, similarity to their own envelope: mean "
        f"{np.mean(scores):.3f}, 10/50/90%: {q[0]:.3f} / {q[1]:.3f} / {q[2]:.3f}"
    )


if __name__ == "__main__":
    main()
