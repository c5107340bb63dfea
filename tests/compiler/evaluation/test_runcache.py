"""The append-only runs file: rows as written, torn or bad lines dropped, other files refused."""

from __future__ import annotations

import re

import pytest
from ngpm_runtime.errors import NgpmError

from ngpm_compiler.evaluation.runcache import append_run, read_runs

FIELDS = ("model", "target", "n", "seed", "similarity", "sha")


def _row(target: str, sim: float) -> dict:
    return {"model": "g", "target": target, "n": 10, "seed": 7, "similarity": sim, "sha": "ab12"}


def test_appended_rows_read_back_as_written(tmp_path):
    path = tmp_path / "runs.csv"
    assert (
        read_runs(path, FIELDS) == [] and path.read_text() == "model,target,n,seed,similarity,sha\n"
    )
    with open(path, "a", encoding="utf-8", newline="") as fh:
        kept = [
            append_run(fh, _row(name, 0.25), FIELDS)
            for name in ("plain", 'comma, "quote"', "new\nline", "é")
        ]
    assert read_runs(path, FIELDS, log=pytest.fail) == kept
    assert kept[1] == {
        "model": "g",
        "target": 'comma, "quote"',
        "n": "10",
        "seed": "7",
        "similarity": "0.25",
        "sha": "ab12",
    }


def test_a_torn_last_line_is_dropped_not_misread(tmp_path):
    """A kill in the middle of `0.4375\\n` leaves `0.43`: the row is dropped (and the file
    rewritten without it, so the next row starts on its own line)."""
    path = tmp_path / "runs.csv"
    read_runs(path, FIELDS)
    with open(path, "a", encoding="utf-8", newline="") as fh:
        first = append_run(fh, _row("a", 0.5), FIELDS)
        append_run(fh, _row("b", 0.4375), FIELDS)
    whole = path.read_bytes()
    path.write_bytes(whole[: whole.rindex(b"0.4375") + 4] + b"\xc3")  # and half a character
    logs: list[str] = []
    assert read_runs(path, FIELDS, log=logs.append) == [first]
    assert logs == [
        f"{path}: dropped 1 unreadable line(s) (a run cut off by an interrupt, or an edit)"
    ]
    assert path.read_bytes() == whole[: whole.index(b"g,b,")]
    for torn in (b"", b"model,tar"):  # killed before or while the header was written
        path.write_bytes(torn)
        assert read_runs(path, FIELDS, log=lambda _m: None) == []
        assert path.read_text() == "model,target,n,seed,similarity,sha\n"


def test_bad_rows_are_dropped(tmp_path):
    path = tmp_path / "runs.csv"
    path.write_text(
        "model,target,n,seed,similarity,sha\n"
        "g,a,10,7,0.5,ab\n"
        "g,b,ten,7,0.5,ab\n"  # not a number
        "g,c,10,7,0.5\n"  # a field short
        "g,d,10,7,0.75,ab\n"
    )
    logs: list[str] = []
    rows = read_runs(path, FIELDS, log=logs.append)
    assert [r["target"] for r in rows] == ["a", "d"]
    assert rows[0] == {
        "model": "g",
        "target": "a",
        "n": "10",
        "seed": "7",
        "similarity": "0.5",
        "sha": "ab",
    }
    assert logs == [
        f"{path}: dropped 2 unreadable line(s) (a run cut off by an interrupt, or an edit)"
    ]
    assert path.read_text().splitlines() == [
        "model,target,n,seed,similarity,sha",
        "g,a,10,7,0.5,ab",
        "g,d,10,7,0.75,ab",
    ]


@pytest.mark.parametrize(
    "data",
    [
        b"name,size\nx,1\n",
        b"\x00\xff\xfe garbage\n",
        b'model,target,n\n"' + b"x" * 200_000 + b'",b,1\n',
        b"model,target,n,similarity\ng,a,10,0.5\n",
    ],
    ids=["another csv", "binary", "huge field", "other columns"],
)
def test_not_a_runs_file_is_a_one_line_error_and_left_alone(tmp_path, data):
    path = tmp_path / "runs.csv"
    path.write_bytes(data)
    with pytest.raises(NgpmError, match=re.escape(f"{path}: not a ")) as err:
        read_runs(path, FIELDS)
    assert "\n" not in str(err.value) and path.read_bytes() == data
