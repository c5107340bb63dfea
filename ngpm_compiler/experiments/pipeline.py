"""`run_eval`: the evaluation's stages (shape, grids, circuit, chain, report) in order, with
their settings kept in the results folder's settings.json."""

from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path
from typing import Any

from ngpm_runtime.errors import NgpmError
from ngpm_runtime.files import atomic_write

from ngpm_compiler.experiments.config import EvalConfig


class EvalError(NgpmError):
    """The evaluation cannot run with the given options or inputs."""


def run_eval(cfg: EvalConfig, command: str = "", log: Any = print) -> dict[str, Any]:
    """Run the selected stages; returns what they produced (for tests)."""
    from ngpm_compiler.experiments import extra, shape
    from ngpm_compiler.experiments.report import write_reports

    t0 = time.perf_counter()
    out, work = Path(cfg.out), Path(cfg.work)
    out.mkdir(parents=True, exist_ok=True)
    work.mkdir(parents=True, exist_ok=True)
    settings_path = out / "settings.json"
    settings: dict[str, Any] = {}
    if settings_path.is_file():
        settings = json.loads(settings_path.read_text(encoding="utf-8"))
    if cfg.stages != ("report",):  # a report-only run keeps the measuring run's settings
        settings.update(cfg.to_json())
    settings["machine"] = f"{platform.machine()}, {os.cpu_count()} cores, {platform.system()}"
    result: dict[str, Any] = {}
    need_shape = any(s in cfg.stages for s in ("shape", "grids"))
    if need_shape:
        from ngpm_compiler.learning.trace_data import load_traces

        targets = shape.test_targets(cfg.shape)
        settings["test_targets"] = {k: len(v) for k, v in targets.items()}
        settings["test_target_names"] = {k: [t.name for t in v] for k, v in targets.items()}
        traces = cfg.shape.traces or shape.tiny_traces(cfg.shape)
        kept = len(load_traces(traces).kept_jobs)
        if kept < 2:
            raise EvalError(f"{traces}: needs at least 2 kept traces, has {kept}")
        settings.update(traces=traces, kept_traces=kept)
        _save_settings(settings_path, settings)
        guides = shape.prepare_guides(cfg.shape, traces, kept, log)
        if "shape" in cfg.stages:
            rows = shape.run_shape(cfg.shape, targets, guides, kept, log)
        else:
            rows = shape.load_rows(cfg.shape)
        result.update(shape.analyze_shape(cfg.shape, rows, kept))
        log(f"shape study done ({len(rows)} runs)")
        if "grids" in cfg.stages:
            result["grids"] = shape.run_grids(cfg.shape, targets, guides, result["summary"], log)
    if "circuit" in cfg.stages:
        result["circuit"] = extra.run_circuit(cfg.circuit, log)
        log("circuit study done")
    if "chain" in cfg.stages:
        result["chain"] = extra.run_chain(cfg.chain, log)
        log("chain study done")
    if command and cfg.stages != ("report",):
        settings.setdefault("commands", {})[",".join(cfg.stages)] = command
    stage_min = dict(settings.get("stage_minutes") or {})
    stage_min[",".join(cfg.stages)] = round((time.perf_counter() - t0) / 60.0, 2)
    settings["stage_minutes"] = stage_min
    settings["wall_minutes"] = round(sum(stage_min.values()), 1)
    _save_settings(settings_path, settings)
    if "report" in cfg.stages:
        readme, report = write_reports(out, command if cfg.stages != ("report",) else "")
        log(f"wrote {readme} and {report}")
    result["files"] = sorted(p.name for p in out.iterdir() if p.is_file())
    return result


def _save_settings(path: Path, settings: dict[str, Any]) -> None:
    atomic_write(path, (json.dumps(settings, indent=1, default=str) + "\n").encode("utf-8"))
