"""Progress: plain periodic lines when the stream is not a terminal, nothing when disabled."""

from __future__ import annotations

import io

from ngpm_compiler.progress import Progress


def test_plain_lines_only_every_interval_and_at_close():
    out = io.StringIO()
    with Progress("traces", 1000, "trace", stream=out, interval=3600) as bar:
        for _ in range(1000):
            bar.update()
    assert out.getvalue() == ""  # a short job prints nothing
    bar = Progress("traces", 1000, "trace", stream=out, interval=3600)
    bar.last -= 3600  # as if an hour had passed
    bar.update()
    for _ in range(999):
        bar.update()
    bar.set_postfix(dropped=4)
    bar.close()
    lines = out.getvalue().splitlines()
    assert len(lines) == 2 and lines[0].startswith("traces: 1/1000 traces, ")
    assert lines[1].startswith("traces: 1000/1000 traces, ") and lines[1].endswith(", dropped 4")
    assert "\r" not in out.getvalue()


def test_a_line_per_interval():
    out = io.StringIO()
    bar = Progress("train", 3, "epoch", initial=1, stream=out, interval=0)
    bar.update()
    bar.update()
    bar.close()
    assert [line.split(" epochs")[0] for line in out.getvalue().splitlines()] == [
        "train: 2/3",
        "train: 3/3",
        "train: 3/3",
    ]


def test_disabled_prints_nothing():
    out = io.StringIO()
    with Progress("x", 5, stream=out, interval=0, enabled=False) as bar:
        bar.update(5)
    assert out.getvalue() == ""
