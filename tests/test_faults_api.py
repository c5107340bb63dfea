"""Issue #12, Python API: bad input raises one clear error that names the cause."""

from __future__ import annotations

from pathlib import Path

import onnx
import pytest
from ngpm_runtime import bundled
from ngpm_runtime.errors import GuideError
from ngpm_runtime.inference.guide import Guide


def _edited_guide(tmp_path: Path, edit) -> Path:
    model = onnx.load(str(bundled.guide_path()))
    edit(model)
    path = tmp_path / "edited.onnx"
    onnx.save(model, str(path))
    return path


def test_guide_without_a_site_output_fails_at_load(tmp_path: Path) -> None:
    """The graph lacks p_3 though the metadata (intact) lists a network for site 3."""

    def drop_output(model):
        keep = [o for o in model.graph.output if o.name != "p_3"]
        del model.graph.output[:]
        model.graph.output.extend(keep)

    path = _edited_guide(tmp_path, drop_output)
    with pytest.raises(GuideError, match=r"has no output p_3 for site 3 .*metadata lists"):
        Guide.load(path, bundled.bundled_program())


def test_guide_with_a_wrong_input_shape_fails_at_load(tmp_path: Path) -> None:
    def narrow(model):
        inp = next(i for i in model.graph.input if i.name == "f_0")
        inp.type.tensor_type.shape.dim[1].dim_value -= 1

    path = _edited_guide(tmp_path, narrow)
    with pytest.raises(GuideError, match=r"input f_0 has shape .* the metadata says"):
        Guide.load(path, bundled.bundled_program())


def test_guide_of_a_future_format_names_the_version(tmp_path: Path) -> None:
    def future(model):
        for prop in model.metadata_props:
            if prop.key == "ngpm_format":
                prop.value = "ngpm-guide-onnx/2"

    path = _edited_guide(tmp_path, future)
    with pytest.raises(
        GuideError,
        match=r"guide format ngpm-guide-onnx/2 is newer than the "
        r"ngpm-guide-onnx/1 this ngpm reads",
    ):
        Guide.load(path, bundled.bundled_program())


def test_intact_guide_still_loads() -> None:
    g = Guide.load(bundled.guide_path(), bundled.bundled_program())
    assert g.nets


def test_stop_pool_returns_when_a_dead_worker_holds_the_queue_lock() -> None:
    """Pool.terminate() waits forever for the task queue's lock when a worker died holding
    it (SIGTERM to the process group); pool_stop gives up after its grace period."""
    import multiprocessing as mp
    import time

    from ngpm_compiler.jobs.pool import stop_pool

    pool = mp.get_context("spawn").Pool(1)
    pool._inqueue._rlock.acquire()  # as a worker killed mid-read leaves it
    t0 = time.perf_counter()
    assert stop_pool(pool, grace=1.0) is False
    assert time.perf_counter() - t0 < 10
    assert all(p.exitcode is not None for p in pool._pool)
    pool._inqueue._rlock.release()  # let the left-behind terminate() thread finish


# --------------------------------------------------------------------------- compile_grammar


@pytest.mark.parametrize(
    "arg, words",
    [
        (None, "got NoneType"),
        (123, "got int"),
        (b"Axiom: F\n", "got bytes: decode them"),
    ],
)
def test_compile_grammar_says_what_it_wants(arg, words) -> None:
    from ngpm_compiler import compile_grammar

    with pytest.raises(TypeError, match="compile_grammar wants a path") as info:
        compile_grammar(arg)
    assert words in str(info.value)


def test_compile_grammar_refuses_a_folder(tmp_path: Path) -> None:
    from ngpm_compiler import GrammarError, compile_grammar

    for arg in (str(tmp_path), tmp_path):
        with pytest.raises(GrammarError, match="is a folder, not a grammar file"):
            compile_grammar(arg)


def test_compile_grammar_refuses_huge_grammars_at_once(tmp_path: Path) -> None:
    import time

    from ngpm_compiler import GrammarError, compile_grammar
    from ngpm_compiler.language.compile import MAX_GRAMMAR_BYTES

    rule = "A(x) : x > 0 --> F(x) [ +(gauss(10, 5)) A(x * 0.9) ] A(x - 0.1)\n"
    text = "derivation length: 5\nAxiom: A(1)\nproduction:\n" + rule * (
        MAX_GRAMMAR_BYTES // len(rule) + 1
    )
    path = tmp_path / "huge.lsys"
    path.write_text(text)
    t0 = time.perf_counter()
    for arg in (path, text):
        with pytest.raises(
            GrammarError,
            match=r"the grammar is 25\d KiB; ngpm reads grammars "
            r"of up to 256 KiB",
        ):
            compile_grammar(arg)
    assert time.perf_counter() - t0 < 2


def test_smc_rejects_a_fractional_particle_count_and_bad_seeds() -> None:
    from ngpm_runtime.inference.smc import SMCOptionError, SMCOptions, smc

    program = bundled.bundled_program()
    with pytest.raises(SMCOptionError, match="particle count must be an integer, got 2.5"):
        smc(program, None, 2.5)
    with pytest.raises(SMCOptionError, match="seed must be a non-negative integer, got -1"):
        smc(program, None, 2, options=SMCOptions(seed=-1))
    with pytest.raises(SMCOptionError, match="max_modules must be an integer >= 1"):
        smc(program, None, 2, options=SMCOptions(max_modules=0))


def test_generate_traces_without_viewport(tmp_path: Path) -> None:
    from ngpm_compiler.learning.shards import TraceError
    from ngpm_compiler.learning.traces import TraceConfig, generate_traces

    g = tmp_path / "nv.lsys"
    g.write_text("Axiom: F F\nendlsystem\n")
    cfg = TraceConfig(grammar=str(g), targets=str(tmp_path), n=1, workers=1)
    with pytest.raises(TraceError, match="no 'viewport:' line"):
        generate_traces(cfg, tmp_path / "tr", progress=False)
    assert not (tmp_path / "tr").exists()


def test_grow_api_takes_the_module_cap(tmp_path: Path) -> None:
    from ngpm_runtime.grow import grow

    from ngpm_compiler.language.compile import compile_grammar

    program = compile_grammar(
        "viewport: -10 10 -10 10\nderivation length: 60\nAxiom: A\n"
        "production:\nA --> A A\nendlsystem\n"
    ).program()
    target = bundled.demo_targets()[0]
    res = grow(program, target, None, 3, max_modules=100)
    assert res.primitives == [] and res.smc.best.limit == "max modules"
    assert res.smc.info["limits"] == {"max modules": 3}
