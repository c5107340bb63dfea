"""docs/api.md: every Python example runs as written, and the API names it lists exist."""

from __future__ import annotations

import contextlib
import importlib
import io
import os
import re
import shutil
from pathlib import Path

import pytest
from PIL import Image
from repo_paths import REPO

API_MD = REPO / "docs" / "api.md"


def examples() -> list[str]:
    return re.findall(r"```python\n(.*?)```", API_MD.read_text(encoding="utf-8"), re.S)


def test_api_md_has_examples() -> None:
    assert len(examples()) >= 4


def test_api_md_examples_run(tmp_path: Path, monkeypatch) -> None:
    shutil.copytree(REPO / "grammars", tmp_path / "grammars")
    monkeypatch.chdir(tmp_path)
    namespace: dict = {"__name__": "api_md"}
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        for k, code in enumerate(examples()):
            exec(compile(code, f"docs/api.md example {k + 1}", "exec"), namespace)
    text = out.getvalue()
    assert re.search(r"^similarity -?[\d.]+ in [\d.]+ s$", text, re.M), text
    assert re.search(r"^unguided: similarity -?[\d.]+$", text, re.M), text
    for name in ("glyph", "horse", "heart", "spiral"):
        assert re.search(rf"^{name} \d+ primitives$", text, re.M), text
    with Image.open(tmp_path / "horse_vine.png") as img:
        img.verify()
    assert (tmp_path / "prior.svg").read_text().startswith("<svg")
    assert re.search(r"^\d+ vertices, \d+ triangles$", text, re.M), text
    assert re.search(r"^crown: similarity -?[\d.]+, \d+ primitives$", text, re.M), text
    for name in ("plant.glb", "plant.obj", "plant.mtl", "plant.ply", "plant.png", "plant.gif"):
        assert (tmp_path / name).stat().st_size > 0, name


def test_first_example_guides_better_than_the_prior(tmp_path: Path, monkeypatch) -> None:
    shutil.copytree(REPO / "grammars", tmp_path / "grammars")
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    with contextlib.redirect_stdout(io.StringIO()):
        for code in examples()[:2]:
            exec(code, namespace)
    sim, raster = namespace["similarity"], namespace["rasterize"]
    t, vp = namespace["target"], namespace["vp"]
    guided = sim(raster(namespace["best"].primitives, vp, *t.size), t.mask)
    unguided = sim(raster(namespace["unguided"].best.primitives, vp, *t.size), t.mask)
    assert guided > unguided


def test_reference_table_names_exist() -> None:
    text = API_MD.read_text(encoding="utf-8")
    rows = re.findall(r"^\| `(ngpm_(?:compiler|runtime)[\w.]*)", text, re.M)
    assert len(rows) >= 15
    for dotted in rows:
        parts = dotted.split(".")
        obj = None
        for i in range(len(parts), 0, -1):
            try:
                obj = importlib.import_module(".".join(parts[:i]))
            except ImportError:
                continue
            for attr in parts[i:]:
                obj = getattr(obj, attr)
            break
        assert obj is not None and callable(obj), dotted


def test_compiler_package_exports() -> None:
    import ngpm_compiler

    for name in ngpm_compiler.__all__:
        assert getattr(ngpm_compiler, name) is not None
    assert "compile_grammar" in dir(ngpm_compiler)
    with pytest.raises(AttributeError):
        ngpm_compiler.no_such_name  # noqa: B018
    from ngpm_compiler import GrammarError, compile_grammar

    with pytest.raises(GrammarError, match="no such grammar file"):
        compile_grammar(os.path.join("nowhere", "x.lsys"))
