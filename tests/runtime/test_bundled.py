"""Package data: the bundled vines sampler is up to date, the bundled guide belongs to it and
was really trained, the demo targets are the ones the project makes, all usable without torch."""

from __future__ import annotations

import hashlib
import json
import textwrap
from pathlib import Path

import numpy as np
import pytest
from blocked_imports import run_blocked
from ngpm_runtime import bundled
from ngpm_runtime.errors import GuideError, ProgramError, TargetError
from ngpm_runtime.inference.guide import Guide
from repo_paths import REPO

VINES = REPO / "grammars" / "vines.lsys"
MIN_TRACES = 500  # the bundled guide comes from scripts/train_vines_guide.sh (3000 traces)


def vines_hash() -> str:
    text = VINES.read_text(encoding="utf-8").replace("\r\n", "\n")
    return "sha256:" + hashlib.sha256(text.encode("utf-8")).hexdigest()


# --- the generated sampler ---------------------------------------------------------------


def test_data_folder_is_flat_so_pyproject_ships_it() -> None:
    # pyproject's package-data is `data/*`: files in subfolders would not be installed
    assert bundled.DATA_DIR == REPO / "runtime" / "ngpm_runtime" / "data"
    assert not [p for p in bundled.DATA_DIR.iterdir() if p.is_dir() and p.name != "__pycache__"]
    # both pyproject files ship the data and py.typed (the runtime's types, PEP 561)
    for path in (REPO / "pyproject.toml", REPO / "runtime" / "pyproject.toml"):
        assert 'ngpm_runtime = ["data/*", "py.typed"]' in path.read_text(), path
    assert (REPO / "runtime" / "ngpm_runtime" / "py.typed").is_file()


def test_bundled_sampler_is_up_to_date_with_vines_lsys() -> None:
    program = bundled.bundled_program()
    assert program.name == "vines"
    assert program.grammar_hash == vines_hash(), (
        "runtime/ngpm_runtime/data/vines_sampler.py is stale: run "
        "`ngpmc compile grammars/vines.lsys -o runtime/ngpm_runtime/data`"
    )


def test_bundled_sites_match_a_fresh_compile() -> None:
    from ngpm_compiler.language.compile import compile_grammar

    compiled = compile_grammar(VINES)
    assert compiled.grammar_hash == vines_hash()
    shipped = json.loads((bundled.DATA_DIR / bundled.SITES_FILE).read_text(encoding="utf-8"))
    assert shipped == compiled.sites_json()
    program, fresh = bundled.bundled_program(), compiled.program()
    assert [s.to_json() for s in program.sites] == [s.to_json() for s in fresh.sites]
    for field in ("viewport", "start", "derivation_length", "angle", "max_primitives", "arity"):
        assert getattr(program, field) == getattr(fresh, field), field
    assert sorted(program.productions) == sorted(fresh.productions)


def test_bundled_program_is_cached_and_samples() -> None:
    from ngpm_runtime.inference.smc import forward

    assert bundled.bundled_program() is bundled.bundled_program()
    a = forward(bundled.bundled_program(), seed=3)
    assert a.primitives and a.primitives[0][0] == "seg"


def test_missing_sampler_is_a_one_line_error(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(bundled, "DATA_DIR", tmp_path)
    with pytest.raises(ProgramError, match="bundled vines sampler is missing") as err:
        bundled.bundled_program()
    assert "\n" not in str(err.value)


# --- the guide ---------------------------------------------------------------------------


def test_bundled_guide_belongs_to_vines_lsys_and_was_trained() -> None:
    guide = bundled.bundled_guide()
    assert isinstance(guide, Guide)
    assert guide.meta["grammar"] == "vines"
    assert guide.meta["grammar_hash"] == vines_hash()
    assert guide.fallback_sites == []  # every site has a network
    assert guide.training["traces"] >= MIN_TRACES, "a tiny development guide was bundled"
    assert "traces" in bundled.guide_summary(guide)


def test_bundled_guide_accepts_a_freshly_compiled_program() -> None:
    from ngpm_compiler.language.compile import compile_grammar

    guide = bundled.bundled_guide(compile_grammar(VINES).program())
    assert guide.program.name == "vines"


def test_bundled_guide_rejects_another_grammar() -> None:
    from ngpm_compiler.language.compile import compile_grammar

    other = compile_grammar(REPO / "grammars" / "chain.lsys").program()
    with pytest.raises(GuideError, match="trained for grammar 'vines'"):
        bundled.bundled_guide(other)


def test_default_guide_by_grammar_and_likelihood() -> None:
    from ngpm_compiler.language.compile import compile_grammar

    vines = bundled.bundled_program()
    assert bundled.default_guide(vines, "shape").path == str(bundled.guide_path())
    circuit = bundled.default_guide(vines, "circuit")  # its own guide, never the shape one
    assert circuit is not None
    assert circuit.path == str(bundled.data_path(bundled.CIRCUIT_GUIDE_FILE))
    assert circuit.path != str(bundled.guide_path())
    other = compile_grammar(REPO / "grammars" / "chain.lsys").program()
    assert bundled.default_guide(other, "shape") is None
    assert bundled.default_guide(other, "circuit") is None


def test_missing_guide_names_the_regeneration_command(tmp_path: Path, monkeypatch) -> None:
    program = bundled.bundled_program()
    monkeypatch.setattr(bundled, "DATA_DIR", tmp_path)
    with pytest.raises(GuideError, match="train_vines_guide.sh") as err:
        bundled.bundled_guide(program)
    assert "\n" not in str(err.value)
    with pytest.raises(GuideError, match="circuit guide is missing.*train_circuit_guide.sh"):
        bundled.bundled_guide(program, "circuit")


# --- demo targets ------------------------------------------------------------------------


def test_demo_targets_load_in_order() -> None:
    targets = bundled.demo_targets()
    assert [t.name for t in targets] == list(bundled.DEMO_TARGETS)
    for t in targets:
        assert t.size == (50, 50)
        assert 0.05 < t.mask.mean() < 0.6
        r, c = t.start_pixel()
        assert t.mask[r, c], f"{t.name}: start is not on the shape"


def test_demo_targets_are_the_ones_the_project_makes() -> None:
    from ngpm_compiler.datasets.demo_targets import make_demo_targets

    made = make_demo_targets()
    assert list(made) == list(bundled.DEMO_TARGETS)
    for t in bundled.demo_targets():
        assert np.array_equal(t.mask, made[t.name].mask), t.name
        assert np.allclose(t.start, made[t.name].start, atol=1e-5), t.name


def test_demo_vase_is_the_closed_mesh_the_project_makes() -> None:
    from ngpm_runtime.geometry.mesh_read import read_mesh
    from ngpm_runtime.volume.voxelize import check_closed

    from ngpm_compiler.datasets.demo_targets import VASE_FILE, vase_obj

    path = bundled.data_path(VASE_FILE)
    assert path.read_text(encoding="utf-8") == vase_obj()
    vertices, faces = read_mesh(path)
    check_closed(vertices, faces, "vase")  # raises on a hole
    assert vertices[:, 1].min() == 0.0 and vertices[:, 1].max() == 1.0


def test_unknown_demo_target() -> None:
    with pytest.raises(TargetError, match="choose from glyph"):
        bundled.demo_target_path("unicorn")


# --- torch-free use ----------------------------------------------------------------------

SCRIPT = textwrap.dedent(
    """
    from ngpm_runtime.bundled import bundled_guide, bundled_program, demo_targets
    from ngpm_runtime.inference.likelihood import ShapeLikelihood
    from ngpm_runtime.inference.smc import SMCOptions, smc

    program = bundled_program()
    guide = bundled_guide(program)
    target = demo_targets()[1]
    vp = program.viewport
    options = SMCOptions(ess_from_proposal=True, start=target.start_pose(vp),
                         canvas_size=target.size, target_mask=target.mask)
    result = smc(program, ShapeLikelihood(target.mask, vp), 4, guide, options)
    assert result.best.primitives
    """
)


def test_guided_smc_with_package_data_needs_no_torch_lark_or_compiler(tmp_path: Path) -> None:
    proc = run_blocked(SCRIPT, tmp_path, timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.strip().endswith("ok")


def _guided_vines(program, guide, target, seed: int, max_steps: int, **options):
    """SMC of the bundled vines and guide into `target`, N = 10, full traces."""
    from ngpm_runtime.inference.likelihood import ShapeLikelihood
    from ngpm_runtime.inference.smc import SMCOptions, TraceRecording, smc

    vp = program.viewport
    return smc(
        program,
        ShapeLikelihood(target.mask, vp),
        10,
        guide,
        options=SMCOptions(
            seed=seed,
            start=target.start_pose(vp),
            canvas_size=target.size,
            target_mask=target.mask,
            trace=TraceRecording.FULL,
            max_steps=max_steps,
            **options,
        ),
    )


def test_guided_runs_repeat_bit_for_bit_and_weights_are_importance_weights() -> None:
    """The bundled guide on vines (the rounds, numpy nets and grouped draws of the fast
    path): a seeded run repeats exactly, and each particle's log weight is its log prior +
    log likelihood - log q, with log q recomputed site by site from its trace."""
    from ngpm_runtime.inference.distributions import proposal_logpdf

    program = bundled.bundled_program()
    guide = bundled.bundled_guide(program)
    target = bundled.demo_targets()[1]

    def run():
        return _guided_vines(program, guide, target, seed=3, max_steps=12, ess_from_proposal=True)

    a, b = run(), run()
    np.testing.assert_array_equal(a.log_weights, b.log_weights)
    assert [p.primitives for p in a.particles] == [p.primitives for p in b.particles]
    # no resampling (ESS never below 1e-9 N): check every weight site by site
    one = _guided_vines(program, guide, target, seed=3, max_steps=4, ess_threshold=1e-9)
    assert one.info["resamples"] == 0
    for p in one.particles:
        log_q = 0.0
        for s, feats, value in p.trace:
            site = program.sites[s]
            params = guide.params(s, feats[None, :])
            # the prior arguments are the feature row's last local columns (float32 holds
            # vines' normal arguments exactly; categorical ones only give the shape)
            lo = 7 + site.arity
            args = feats[None, lo : lo + site.n_args()].astype(np.float64)
            log_q += float(proposal_logpdf(site, args, params, np.array([value]))[0])
        want = p.log_prior + p.log_likelihood - log_q
        assert p.log_weight == pytest.approx(want, abs=1e-4)
