"""Hostile trace files: every malformed shard, pending job or manifest.json (made here from a
good traces directory) stops `load_traces` / `ngpmc train` and a resumed `ngpmc traces` with
one line that names the file and the field, and nothing is built on top of it. These used to
give tracebacks, or a resume that counted rows twice (a short `jobs` array)."""

from __future__ import annotations

import io
import json
import shutil
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from fixtures.datasets import CHAIN, make_dataset

from ngpm_compiler.cli import main
from ngpm_compiler.learning.shards import TraceError
from ngpm_compiler.learning.trace_data import load_traces
from ngpm_compiler.learning.trace_store import TraceStore, save_npz
from ngpm_compiler.learning.traces import TraceConfig, generate_traces

SHARD = "shard_00000002.npz"  # the middle one of three shards of two jobs


def config(data: Path) -> TraceConfig:
    return TraceConfig(grammar=CHAIN, targets=str(data), n=6, particles=4, workers=1, shard_size=2)


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> tuple[Path, Path]:
    """(dataset, a finished traces directory: shards 0, 2 and 4 of two jobs each)."""
    root = tmp_path_factory.mktemp("shards")
    data = make_dataset(root / "data", 2)
    generate_traces(config(data), root / "good", progress=False)
    assert sorted(p.name for p in (root / "good").glob("shard_*")) == [
        "shard_00000000.npz",
        SHARD,
        "shard_00000004.npz",
    ]
    return data, root / "good"


def copy(good: Path, tmp_path: Path) -> Path:
    out = tmp_path / "tr"
    shutil.copytree(good, out)
    return out


def edited(edit: Callable[[dict], None]) -> Callable[[Path], None]:
    """Rewrites a shard with `edit` applied to its arrays."""

    def apply(path: Path) -> None:
        with np.load(path) as z:
            arrays = {k: z[k] for k in z.files}
        edit(arrays)
        save_npz(path, arrays)

    return apply


def rename(a: dict) -> None:
    a["jobz"] = a.pop("jobs")


def short_jobs(a: dict) -> None:
    """The per-job arrays of the first job only: the rows of the second job stay."""
    for k in ("jobs", "kept", "n_prims", "target", "seed"):
        a[k] = a[k][:1]


def replaced(key: str, make: Callable[[np.ndarray], np.ndarray]) -> Callable[[Path], None]:
    def edit(a: dict) -> None:
        a[key] = make(a[key])

    return edited(edit)


def nan_at(x: np.ndarray) -> np.ndarray:
    x = x.copy()
    x.flat[0] = np.nan
    return x


def npy(path: Path) -> None:
    buf = io.BytesIO()
    np.save(buf, np.arange(3))
    path.write_bytes(buf.getvalue())


def pickled(path: Path) -> None:
    np.savez(path.with_suffix(""), jobs=np.array([object()], dtype=object))


SHARD_CASES = {
    "wrong key": (edited(rename), "no array 'jobs'"),
    "unknown array": (edited(lambda a: a.update(x_0=a["v_0"])), "unexpected array 'x_0'"),
    "wrong width": (
        replaced("f_0", lambda x: x[:, :-1]),
        "'f_0' has 108 feature columns; site 0 has 109",
    ),
    "wrong dtype": (
        replaced("jobs", lambda x: x.astype(np.float64)),
        "'jobs' has dtype float64, not int64",
    ),
    "features float64": (
        replaced("f_0", lambda x: x.astype(np.float64)),
        "'f_0' has dtype float64, not float32",
    ),
    "short jobs array": (
        replaced("jobs", lambda x: x[:1]),
        "the per-job arrays differ in length (jobs 1, kept 2, n_prims 2, target 2, seed 2)",
    ),
    "rows of a job it does not list": (
        edited(short_jobs),
        "'j_0' names job 3, not a kept job of this file",
    ),
    "NaN value": (replaced("v_0", nan_at), "'v_0' holds NaN or infinite values"),
    "infinite feature": (
        replaced("f_0", lambda x: x + np.inf),
        "'f_0' holds NaN or infinite values",
    ),
    "site lengths": (
        replaced("v_0", lambda x: x[:-1]),
        "the arrays of site 0 differ in length (f_0 24, v_0 23, j_0 24)",
    ),
    "missing site array": (edited(lambda a: a.pop("j_0")), "no array 'j_0'"),
    "2-d jobs": (replaced("jobs", lambda x: x.reshape(1, -1)), "'jobs' has shape (1, 2)"),
    "repeated job": (
        replaced("jobs", lambda x: np.array([2, 2])),
        "'jobs' holds a negative or repeated job id",
    ),
    "site of no grammar": (
        edited(lambda a: a.update(f_9=a["f_0"], v_9=a["v_0"], j_9=a["j_0"])),
        "'f_9': the grammar has no site 9",
    ),
    "truncated file": (
        lambda p: p.write_bytes(p.read_bytes()[:300]),
        "not a readable npz file (BadZipFile)",
    ),
    "not an npz": (lambda p: p.write_bytes(b"hello"), "not a readable npz file"),
    "one npy array": (npy, "not an npz file (a single array)"),
    "pickled objects": (pickled, "array 'jobs' cannot be read (ValueError)"),
}


@pytest.mark.parametrize("case", sorted(SHARD_CASES))
def test_malformed_shard_is_refused_naming_file_and_field(case: str, good, tmp_path) -> None:
    data, src = good
    damage, words = SHARD_CASES[case]
    out = copy(src, tmp_path)
    damage(out / SHARD)
    before = sorted(p.name for p in out.rglob("*"))
    with pytest.raises(TraceError) as info:  # resuming (with -n raised) builds nothing on it
        generate_traces(replace(config(data), n=10), out, progress=False)
    assert str(info.value).startswith(f"{out / SHARD}: corrupt trace shard: {words}")
    assert sorted(p.name for p in out.rglob("*")) == before
    with pytest.raises(TraceError) as info:
        load_traces(out)
    assert f"unreadable {SHARD} ({words}" in str(info.value)
    assert "4 of the 6 kept traces are there" in str(info.value)


def test_malformed_pending_job_and_a_job_in_two_shards(good, tmp_path) -> None:
    data, src = good
    out = copy(src, tmp_path)
    pending = out / "pending" / "job_00000007.npz"
    pending.parent.mkdir(exist_ok=True)
    shutil.copy(out / SHARD, pending)
    with pytest.raises(
        TraceError,
        match=f"{pending}: corrupt trace shard: 'jobs' does not "
        "hold the one job the file is named for",
    ):
        load_traces(out)
    pending.unlink()
    shutil.copy(out / SHARD, out / "shard_00000003.npz")
    with pytest.raises(TraceError, match=f"job 2 is in two shards, {SHARD} and shard_00000003.npz"):
        generate_traces(config(data), out, progress=False)


def without(key: str) -> Callable[[dict], dict]:
    return lambda m: {k: v for k, v in m.items() if k != key}


MANIFEST_CASES = {
    "not JSON": ("{", "corrupt manifest (not JSON)"),
    "a list": ([], "corrupt manifest: not a JSON object"),
    "no sites": (without("sites"), "corrupt manifest: no field 'sites'"),
    "kept a string": (
        lambda m: {**m, "kept": "6"},
        "corrupt manifest: 'kept' is not a whole number >= 0",
    ),
    "negative seconds": (
        lambda m: {**m, "seconds": -1.0},
        "corrupt manifest: 'seconds' is not a finite number >= 0",
    ),
    "job seconds": (
        lambda m: {**m, "job_seconds": [0.1, "x"]},
        "corrupt manifest: 'job_seconds' or 'shards' holds 'x'",
    ),
    "key without grammar": (
        lambda m: {**m, "key": {}},
        "corrupt manifest: 'key' has no grammar name",
    ),
    "site without kind": (
        lambda m: {**m, "sites": [{"index": 0, "id": "x"}]},
        "corrupt manifest: 'sites' entry 0 needs an index, an id and a kind",
    ),
    "layouts of other sites": (
        lambda m: {**m, "layouts": {}},
        "corrupt manifest: 'layouts' has sites [], 'sites' has ['0']",
    ),
    "layout not ranges": (
        lambda m: {**m, "layouts": {"0": {"local": [5, 1]}}},
        "corrupt manifest: 'layouts' entry '0' is not a set of [start, stop] column ranges",
    ),
    "layout without context": (
        lambda m: {
            **m,
            "layouts": {
                i: {g: r for g, r in lay.items() if g != "context"}
                for i, lay in m["layouts"].items()
            },
        },
        "corrupt manifest: 'layouts' entry '0' is not a set of [start, "
        "stop] column ranges of the groups local, target, partial, "
        "context",
    ),
}


@pytest.mark.parametrize("case", sorted(MANIFEST_CASES))
def test_malformed_manifest_is_refused_naming_the_field(case: str, good, tmp_path) -> None:
    data, src = good
    edit, words = MANIFEST_CASES[case]
    out = copy(src, tmp_path)
    path = out / "manifest.json"
    if isinstance(edit, str):
        path.write_text(edit)
    else:
        m = json.loads(path.read_text())
        path.write_text(json.dumps(edit(m) if callable(edit) else edit))
    for call in (
        lambda: load_traces(out),
        lambda: generate_traces(config(data), out, progress=False),
    ):
        with pytest.raises(TraceError) as info:
            call()
        assert str(info.value).startswith(f"{path}: {words}")


def test_good_manifest_passes(good) -> None:
    from ngpm_compiler.learning.shards import check_manifest

    _, src = good
    check_manifest(src / "manifest.json", json.loads((src / "manifest.json").read_text()))
    assert len(load_traces(src).kept_jobs) == 6


def one_error_line(capsys, *args: str) -> str:
    code = main(list(args))
    err = capsys.readouterr().err
    assert code == 1 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    return err.strip()


def test_cli_train_and_resumed_traces_on_malformed_files(good, tmp_path, capsys) -> None:
    data, src = good
    out = copy(src, tmp_path)
    replaced("f_0", lambda x: x[:, :-1])(out / SHARD)
    line = one_error_line(capsys, "train", str(out), "-o", str(tmp_path / "m.pt"))
    assert f"unreadable {SHARD} ('f_0' has 108 feature columns; site 0 has 109)" in line
    line = one_error_line(
        capsys,
        "traces",
        CHAIN,
        "--targets",
        str(data),
        "-n",
        "8",
        "--particles",
        "4",
        "--workers",
        "1",
        "--shard-size",
        "2",
        "-o",
        str(out),
    )
    assert line == (
        f"ngpmc: error: {out / SHARD}: corrupt trace shard: 'f_0' has 108 "
        "feature columns; site 0 has 109"
    )
    (out / "manifest.json").write_text(json.dumps({"format": "ngpm-traces/1"}))
    line = one_error_line(capsys, "train", str(out), "-o", str(tmp_path / "m.pt"))
    assert line == f"ngpmc: error: {out / 'manifest.json'}: corrupt manifest: no field 'key'"
    assert not (tmp_path / "m.pt").exists()
    assert TraceStore(out).pending_paths() == []
