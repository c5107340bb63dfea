"""`ngpmc learn`'s command line (the run itself: tests/compiler/experiments/test_learn.py):
bad options are one line before any work."""

from __future__ import annotations

import pytest
from fixtures.datasets import CHAIN

from ngpm_compiler.cli import main


@pytest.mark.parametrize("budget", ["5q", "0s", "m", "-1h"])
def test_a_bad_budget_is_refused_while_parsing(tmp_path, capsys, budget):
    with pytest.raises(SystemExit) as err:
        main(["learn", CHAIN, "-o", str(tmp_path / "out"), f"--budget={budget}"])
    assert err.value.code == 2
    assert "argument --budget: not a duration such as 45m, 2h or 90s" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    "argv, message",
    [
        (
            ["--likelihood", "circuit", "--targets", "x"],
            "the circuit likelihood has no targets: drop --targets",
        ),
        (["--targets", "nowhere"], "--targets nowhere: no such directory of targets"),
    ],
)
def test_inputs_it_cannot_use_are_one_line(tmp_path, capsys, argv, message):
    assert main(["learn", CHAIN, "-o", str(tmp_path / "out"), *argv]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"ngpmc: error: {message}") and len(err.splitlines()) == 1


def test_a_sampler_module_is_refused(tmp_path, capsys):
    sampler = tmp_path / "chain_sampler.py"
    sampler.write_text("")
    assert main(["learn", str(sampler), "-o", str(tmp_path / "out")]) == 1
    assert "ngpmc learn takes a grammar's .lsys file" in capsys.readouterr().err
