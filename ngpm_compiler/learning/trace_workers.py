"""What runs in a trace worker (a local process or a Ray task): its state, set up from the
grammar's text, the targets and the guide (no file read on another machine), and one job."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

import numpy as np
from ngpm_runtime.errors import SMCFailed

from ngpm_compiler.jobs import backends, pool
from ngpm_compiler.learning.trace_jobs import job_arrays, job_spec, run_job, run_own_job

if TYPE_CHECKING:
    from ngpm_runtime.image.targets import Target

JobArgs = tuple[int, int, int, int, int | None]  # job, base seed, particles, min prims, cap


def worker_setup(
    grammar: str,
    text: str,
    targets: list[Target],
    guide: str | bytes | None = None,
    likelihood: str = "shape",
    sigma: float | None = None,
    own_size: int = 0,
) -> dict[str, Any]:
    """A worker's state from the grammar file's name and text, the targets, the guide
    (its path, or its file's bytes for workers on other machines), the likelihood and its
    sigma (3D, None: the default), so a worker on another machine reads no file. own_size:
    jobs record ground-truth traces into envelopes of that size (`run_own_job`; 0: SMC
    into the targets)."""
    import os

    os.environ.setdefault("OMP_NUM_THREADS", "1")
    from ngpm_compiler.language.compile import load_grammar

    program = load_grammar(grammar, text)
    proposal = None if guide is None else backends.load_guide(guide, program)
    return {
        "program": program,
        "targets": targets,
        "guide": proposal,
        "likelihood": likelihood,
        "sigma": sigma,
        "own_size": own_size,
    }


def do_job(args: JobArgs) -> tuple[dict[str, np.ndarray], float]:
    """One trace job in a worker: its npz arrays (`job_arrays`) and the seconds it took."""
    job, base_seed, particles, min_prims, max_modules = args
    t0 = time.perf_counter()
    if pool.state().get("own_size"):
        seed = job_spec(base_seed, job, 1)[1]
        trace, n_prims = run_own_job(
            pool.state()["program"], seed, pool.state()["own_size"], max_modules
        )
        kept = n_prims >= max(1, min_prims)
        return job_arrays(job, 0, seed, trace, n_prims, kept), time.perf_counter() - t0
    targets = pool.state()["targets"]
    ti, seed = job_spec(base_seed, job, len(targets))
    try:
        trace, n_prims = run_job(
            pool.state()["program"],
            targets[ti],
            seed,
            particles,
            guide=pool.state().get("guide"),
            max_modules=max_modules,
            likelihood=pool.state().get("likelihood", "shape"),
            sigma=pool.state().get("sigma"),
        )
    except SMCFailed:  # every particle died: a property of the job, so it is dropped
        trace, n_prims = [], -1
    kept = n_prims >= min_prims
    return job_arrays(job, ti, seed, trace, n_prims, kept), time.perf_counter() - t0
