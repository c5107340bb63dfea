"""What the first choice is worth: guided SMC whose depth-0 choice is the target's own
(experiments/notes/far_lookahead.md).

    python experiments/first_choice_oracle.py GRAMMAR GUIDE [--targets 24] [--runs 8] \
        [--choice-temperature 0.5]

Targets: envelopes of forward samples (trace_jobs.own_sample, seeds 5000, 5001, ...), whose
sample, and so its first choice (the value of the first site visit, at derivation depth 0),
is known. Guided SMC at N = 10 with the guide as it is, and with the guide except that
every depth-0 visit proposes the sample's own value (probability 1; the weights stay exact
importance weights of that proposal). Both run the Python deriver (a proposal that is not a
Guide). Prints the mean over targets of the median similarity of each, and of the sample
itself drawn into its own envelope (the ceiling).
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np
from ngpm_runtime.grow import grow
from ngpm_runtime.inference.guide import Guide, ProposalSettings
from ngpm_runtime.program import Site
from top_choice import DEPTH_COL  # experiments/, beside this

from ngpm_compiler.language.compile import load_grammar
from ngpm_compiler.learning.trace_jobs import own_sample


class FirstChoiceOracle:
    """The guide's choice probabilities, the depth-0 rows' replaced by the known value."""

    uses_features = True

    def __init__(self, guide: Guide, first: int) -> None:
        self.guide, self.first = guide, first
        self.feature_context = guide.feature_context
        self.feature_far = guide.feature_far
        self.settings = guide.settings

    def propose(
        self, site: Site, prior_args: np.ndarray, features: Any, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        x = self.guide._input(site.index, features, len(features))
        p = np.asarray(self.guide.params(site.index, x), dtype=np.float64)
        p = p / p.sum(1, keepdims=True)
        top = features[:, DEPTH_COL] == 0
        p[top] = 0.0
        p[top, self.first] = 1.0
        v = (rng.random(len(p))[:, None] > np.cumsum(p, 1)).sum(1).clip(0, p.shape[1] - 1)
        return v.astype(np.float64), np.log(p[np.arange(len(p)), v])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("grammar")
    ap.add_argument("guide")
    ap.add_argument("--targets", type=int, default=24)
    ap.add_argument("--runs", type=int, default=8)
    ap.add_argument("--choice-temperature", type=float, default=0.5)
    a = ap.parse_args()
    program = load_grammar(a.grammar)
    if len(program.sites) != 1 or program.sites[0].kind != "categorical":
        raise SystemExit(f"{a.grammar}: this probe is for a grammar with one choice site")
    guide = Guide.load(a.guide, program, ProposalSettings(1.0, a.choice_temperature, 0.5))
    scores: dict[str, list[float]] = {"guide": [], "guide, first choice known": [], "own": []}
    for i in range(a.targets):
        found = own_sample(program, 5000 + i, 50)
        assert found is not None, "a sample that draws enough"
        sample, target = found
        first = int(sample.trace[0][2])
        for name, prop in (
            ("guide", guide),
            ("guide, first choice known", FirstChoiceOracle(guide, first)),
        ):
            runs = [grow(program, target, prop, 10, 1000 * i + r).similarity for r in range(a.runs)]
            scores[name].append(float(np.median(runs)))
        values = [(s, v) for s, _, v in sample.trace]
        scores["own"].append(grow(program, target, _Replay(values), 1, 0).similarity)
    for name, vals in scores.items():
        print(f"{name}: {np.mean(vals):.3f}")


class _Replay:
    """The sample's own values, in order (one particle)."""

    uses_features = False

    def __init__(self, values: list[tuple[int, float]]) -> None:
        self.values, self.k = values, 0

    def propose(
        self, site: Site, prior_args: np.ndarray, features: Any, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        v = np.array([self.values[self.k][1]], dtype=np.float64)
        self.k += 1
        p = np.asarray(prior_args, dtype=np.float64)[0]
        return v, np.log(p[int(v[0])] / p.sum()) * np.ones(1)


if __name__ == "__main__":
    main()
