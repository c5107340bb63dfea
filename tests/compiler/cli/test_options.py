"""Issue #27, finding 7: every option value of every `ngpmc` command is checked while the
command line is parsed: a bad number, list or output name ends in argparse's one `error:`
line naming the option and its rule (exit code 2), never in a traceback, a MemoryError or
a silently wrong result. The fuzz test below tries bad values on every option."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from ngpm_compiler import cli
from ngpm_compiler.cli import build_parser, main

# values tried on every option that takes one
BAD = [
    "0",
    "-1",
    "-3",
    "nan",
    "inf",
    "-inf",
    "",
    ",,",
    "1,,2",
    "100000",
    "1e18",
    "1" + "0" * 30,
    "x",
    "FOLDER",
]
# refused by every option that refuses the non-number "x" (numbers, lists, choices)
NOT_A_COUNT = ["-1", "-3", "nan", "inf", "-inf", "", ",,", "1,,2", "1e18", "1" + "0" * 30]
ZERO_IS_VALID = {"--hidden", "--port", "--seed"}  # 0: automatic, any free port, a seed


def run(capsys, argv: list[str]) -> tuple[int, str]:
    try:
        code = main(argv)
    except SystemExit as stop:  # argparse refuses the command line
        code = int(stop.code or 0)
    out, err = capsys.readouterr()
    return code, err


def one_error_line(code: int, err: str) -> str:
    """Exit code != 0, no traceback, one `error:` line (argparse's usage may precede it)."""
    assert code != 0, err
    assert "Traceback" not in err, err
    lines = [x for x in err.strip().splitlines() if not x.startswith(("usage:", " "))]
    assert len(lines) == 1 and "error: " in lines[0], err
    return lines[0]


def commands(
    parser: argparse.ArgumentParser, path: tuple[str, ...] = ()
) -> dict[tuple[str, ...], argparse.ArgumentParser]:
    """Every (sub)command's parser, by its words: ('targets', 'show') -> parser."""
    out = {path: parser} if path else {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                out.update(commands(sub, (*path, name)))
    return out


def value_options(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    """The options that take a value (not flags, not positionals, not --help)."""
    return [a for a in parser._actions if a.option_strings and a.nargs != 0]


def bases(tmp: Path) -> dict[tuple[str, ...], list[str]]:
    """For each command, a command line that stops quickly with a one-line error after
    parsing (an input is missing), whatever valid value one option gets."""
    gone = str(tmp / "missing")
    blocker = tmp / "a_file"
    blocker.write_text("not a folder")
    return {
        ("compile",): ["compile", f"{gone}.lsys"],
        ("check",): ["check", f"{gone}.lsys"],
        ("sample",): ["sample", f"{gone}.lsys", "-o", str(tmp / "s.png")],
        ("traces",): ["traces", f"{gone}.lsys", "--targets", gone, "-o", str(tmp / "tr")],
        ("train",): ["train", gone, "-o", str(tmp / "m.pt")],
        ("learn",): ["learn", f"{gone}.lsys", "-o", str(tmp / "learn")],
        ("iterate",): [
            "iterate",
            f"{gone}.lsys",
            "--targets",
            gone,
            "--validate",
            f"v={gone}",
            "-o",
            str(tmp / "it"),
        ],
        ("export",): ["export", f"{gone}.pt", "-o", str(tmp / "g.onnx")],
        ("tune",): [
            "tune",
            f"{gone}.lsys",
            f"{gone}.onnx",
            "--validate",
            f"v={gone}",
            "-o",
            str(tmp / "t.onnx"),
        ],
        ("grow",): ["grow", f"{gone}.png"],
        ("targets", "build"): [
            "targets",
            "build",
            "silhouettes",
            "-o",
            str(tmp / "ds"),
            "--from",
            gone,
        ],
        ("targets", "list"): ["targets", "list", "--nope"],
        ("targets", "show"): ["targets", "show", f"{gone}.png", "-o", str(tmp / "sheet.png")],
        ("eval",): ["eval", "-o", str(tmp / "ev"), "--traces", gone, "--glyphs", gone],
        ("demo",): ["demo", "-o", str(blocker / "out")],
        ("serve",): ["serve", "--grammar", f"{gone}.lsys"],
    }


# a valid value here would do the command's real work: only its parsing is tried
PARSE_ONLY = {(("demo",), "-o")}


def test_every_command_has_a_fuzz_base(tmp_path: Path) -> None:
    assert set(commands(build_parser())) == set(bases(tmp_path)) | {("targets",)}


def test_numeric_options_have_checked_types() -> None:
    """No bare int or float: each number has a range that argparse checks."""
    loose = [
        f"{' '.join(words)} {a.option_strings[0]}"
        for words, parser in commands(build_parser()).items()
        for a in value_options(parser)
        if a.type in (int, float)
    ]
    assert not loose


def fuzz_one(
    capsys,
    argv: list[str],
    action: argparse.Action,
    value: str,
    refuses_text: bool,
    parse_only: bool,
) -> None:
    """One bad value on one option: refused at parsing where it must be, else a clean
    one-line failure of the (fast-failing) base command."""
    option = action.option_strings[-1]
    if parse_only:
        try:
            cli.build_parser().parse_args([*argv, option, value])
            return
        except SystemExit:
            capsys.readouterr()
    code, err = run(capsys, [*argv, option, value])
    line = one_error_line(code, err)
    must_refuse = refuses_text and (
        value in NOT_A_COUNT or (value == "0" and option not in ZERO_IS_VALID)
    )
    if must_refuse:
        names = "/".join(action.option_strings)
        assert code == 2 and f"argument {names}: " in line, (value, line)


def test_option_fuzz(tmp_path: Path, capsys, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every option of every command, every bad value: one error line, no traceback;
    numbers, lists and choices refuse them while parsing, naming the option."""
    monkeypatch.chdir(tmp_path)  # relative values such as "x" land here
    parser = build_parser()
    monkeypatch.setattr(cli, "build_parser", lambda: parser)  # built once: 10x faster
    folder = tmp_path / "folder"
    folder.mkdir()
    tried = 0
    argvs = bases(tmp_path)
    for words, sub in commands(parser).items():
        argv = argvs.get(words, [])
        for action in value_options(sub):
            option = action.option_strings[-1]
            try:
                sub.parse_args([*argv[len(words) :], option, "x"])
                refuses_text = False
            except SystemExit:
                refuses_text = True
            capsys.readouterr()
            for value in BAD:
                value = str(folder) if value == "FOLDER" else value
                fuzz_one(
                    capsys,
                    argv,
                    action,
                    value,
                    refuses_text,
                    (words, action.option_strings[0]) in PARSE_ONLY,
                )
                tried += 1
    assert tried > 800


@pytest.mark.parametrize(
    "argv, words",
    [
        (["train", "t", "-o", "m.pt", "--K", "-1"], "argument --K: must be from 1 to 64, got -1"),
        (["train", "t", "-o", "m.pt", "--K", "0"], "argument --K: must be from 1 to 64, got 0"),
        (
            ["train", "t", "-o", "m.pt", "--batch-size", "0"],
            "argument --batch-size: must be from 1",
        ),
        (["train", "t", "-o", "m.pt", "--hidden", "-1"], "argument --hidden: must be from 0 to"),
        (
            ["train", "t", "-o", "m.pt", "--lr", "nan"],
            "argument --lr: must be a number above 0 and at most 1, got nan",
        ),
        (["train", "t", "-o", "m.pt", "--epochs", "0"], "argument --epochs: must be from 1 to"),
        (["train", "t", "-o", "m.pt", "--patience", "0"], "argument --patience: must be from 1"),
        (["train", ",,", "-o", "m.pt"], "argument traces: an empty list"),
        (["train", "a,,b", "-o", "m.pt"], "argument traces: an empty item in the list 'a,,b'"),
        (["train", "t", "-o", "m.txt"], "argument -o/--out: the output must be a .pt file"),
        (["export", "m.pt", "-o", "x.txt"], "argument -o/--out: the output must be a .onnx file"),
        (
            ["tune", "g.lsys", "g.onnx", "-o", "t.onnx", "--validate", ""],
            "argument --validate: an empty list",
        ),
        (
            ["tune", "g.lsys", "g.onnx", "-o", "t.onnx", "--validate", "v=a,v=b"],
            "argument --validate: the name 'v' is given twice",
        ),
        (
            ["tune", "g.lsys", "g.onnx", "-o", "t.onnx", "--validate", "v="],
            "argument --validate: 'v=': expected NAME=PATH",
        ),
        (
            ["tune", "g.lsys", "g.onnx", "-o", "t.onnx", "--validate", "v=a", "--ess", "0"],
            "argument --ess: ess_threshold must be in (0, 1] or none, got 0.0",
        ),
        (
            [
                "tune",
                "g.lsys",
                "g.onnx",
                "-o",
                "t.onnx",
                "--validate",
                "v=a",
                "--temperatures",
                "inf",
            ],
            "argument --temperatures: temperature must be a number in [0.05, 20], got inf",
        ),
        (["targets", "show", "d", "-o", "s.png", "--cell", "0"], "argument --cell: must be from 8"),
        (["targets", "show", "d", "-o", "s.png", "--cell", "100000"], "must be from 8 to 256"),
        (
            ["targets", "show", "d", "-o", "s.png", "--cols", "-3"],
            "argument --cols: must be from 1",
        ),
        (["targets", "show", "d", "-o", "s.png", "--max", "0"], "argument --max: must be from 1"),
        (["targets", "show", "d", "-o", "sheet.txt"], "the output must be a .png file"),
        (["targets", "build", "scribbles", "-o", "d", "--count", "0"], "argument --count"),
        (
            ["grow", "x.png", "--size", "100000"],
            "argument --size: target sizes are 8 to 1024 pixels, got 100000",
        ),
        (["traces", "g", "--targets", "t", "-o", "o", "--size", "100000"], "target sizes are 8"),
        (["traces", "g", "--targets", "t", "-o", "o", "--shard-size", "0"], "--shard-size"),
        (
            ["traces", "g", "--targets", "t", "-o", "", "-n", "5"],
            "argument -o/--out: an empty path",
        ),
        (
            [
                "iterate",
                "g",
                "--targets",
                "t",
                "--validate",
                "v=d",
                "-o",
                "o",
                "--val-targets",
                "0",
            ],
            "argument --val-targets: must be from 1",
        ),
        (["iterate", "g", "--targets", "t,", "--validate", "v=d", "-o", "o"], "an empty item"),
        (
            ["eval", "-o", "x", "--stages", "heldout,nope"],
            "argument --stages: unknown stage nope; choose from shape",
        ),
        (["eval", "-o", "x", "--ns", "1,,2"], "argument --ns: an empty item"),
        (["serve", "--port", "70000"], "argument --port: must be from 0 to 65535, got 70000"),
        (["serve", "--timeout", "nan"], "argument --timeout: must be a number above 0"),
        (["demo", "-N", "0"], "argument -N/--particles: must be from 1 to 100000, got 0"),
        (["demo", "--runs", "0"], "argument --runs: must be from 1"),
        (["sample", "g.lsys", "-o", "s.png", "--max-modules", "0"], "argument --max-modules"),
    ],
)
def test_bad_values_are_refused_at_parsing(
    capsys, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, argv: list[str], words: str
) -> None:
    monkeypatch.chdir(tmp_path)
    code, err = run(capsys, argv)
    line = one_error_line(code, err)
    assert code == 2 and words in line, line
    assert not list(tmp_path.iterdir())  # refused before anything was written


def test_valid_values_still_parse() -> None:
    parser = build_parser()
    args = parser.parse_args(
        [
            "tune",
            "g.lsys",
            "g.onnx",
            "-o",
            "T.ONNX",
            "--validate",
            " v = a/b , c/d.x ",
            "--ess",
            "none,0.5",
            "--temperatures",
            "1, 0.5",
        ]
    )
    assert args.validate == {"v": "a/b", "d": "c/d.x"}
    assert args.ess == (None, 0.5) and args.temperatures == (1.0, 0.5)
    args = parser.parse_args(["train", "a, b", "-o", "m.pt", "--hidden", "0", "--lr", "1"])
    assert args.traces == ("a", "b") and args.hidden == 0 and args.lr == 1.0
    args = parser.parse_args(["eval", "-o", "x", "--stages", "heldout", "--ns", "1,10"])
    assert args.stages == ("heldout",) and args.ns == (1, 10)
    assert parser.parse_args(["eval", "-o", "x"]).heldout_guides == {}
    assert (
        parser.parse_args(
            ["iterate", "g", "--targets", "t", "--validate", "d", "-o", "o"]
        ).init_traces
        == ()
    )
    assert parser.parse_args(["serve", "--port", "0"]).port == 0


def test_every_option_names_its_default() -> None:
    """`--help` shows every default: an option that takes a value and is not required says
    what it is when not given."""
    missing = []
    for path, parser in commands(build_parser()).items():
        for action in value_options(parser):
            if action.required or action.help == argparse.SUPPRESS:
                continue
            if "default" not in (action.help or ""):
                missing.append(f"{' '.join(path)} {action.option_strings[0]}")
    assert not missing, missing
