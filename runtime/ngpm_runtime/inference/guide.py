"""A learned guide: the ONNX file written by `ngpmc export`, run with onnxruntime.

`Guide.load(path, program)` checks that the file is an ngpm guide for this grammar (hash and
site table); `Guide.propose` implements the Proposal protocol (docs/architecture.md section 5):
one onnxruntime call per propose (one small session per site net when the `onnx`
package can split the file), then sampling with distributions.proposal_draw. Sites without a
network (unseen in training) fall back to the prior; they are listed in `Guide.fallback_sites`.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort

from ngpm_runtime.errors import GuideError
from ngpm_runtime.inference import distributions as dist
from ngpm_runtime.program import Program, Site

ONNX_FORMAT = "ngpm-guide-onnx/1"
SITE_KEYS = ("id", "kind", "k")  # what must agree between the guide's and program's sites


class Guide:
    """Proposal that runs the per-site networks of one ONNX file."""

    def __init__(self, session: ort.InferenceSession, program: Program, path: str,
                 meta: dict[str, Any]) -> None:
        self.session = session
        self.program = program
        self.path = path
        self.meta = meta
        self.nets: dict[int, dict[str, Any]] = {int(k): v for k, v in meta["nets"].items()}
        self.feature_set: str = meta["features"].get("feature_set", "all")
        self.uses_features = self.feature_set != "const"
        self.K = int(meta["K"])
        self.training: dict[str, Any] = meta["training"]
        self.fallback_sites: list[int] = [s.index for s in program.sites
                                          if s.index not in self.nets]
        self._empty = {f"f_{i}": np.zeros((0, n["n_f"]), dtype=np.float32)
                       for i, n in self.nets.items()}
        # one small session per site net when the `onnx` package can split the file
        self.site_sessions: dict[int, ort.InferenceSession] = {}

    @classmethod
    def load(cls, path: str | Path, program: Program) -> Guide:
        path = str(path)
        if not Path(path).is_file():
            raise GuideError(f"{path}: no such guide file")
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = 1
        opts.inter_op_num_threads = 1
        opts.log_severity_level = 3
        try:
            session = ort.InferenceSession(path, opts, providers=["CPUExecutionProvider"])
            props = session.get_modelmeta().custom_metadata_map
        except Exception:  # onnxruntime raises several types for unreadable files
            raise GuideError(f"{path}: not a readable ONNX guide (corrupt or truncated file)") \
                from None
        if props.get("ngpm_format") != ONNX_FORMAT:
            raise GuideError(format_message(path, props.get("ngpm_format")))
        try:
            meta = {k: props[k] for k in ("grammar", "grammar_hash", "K")}
            for key in ("sites", "features", "nets", "training"):
                meta[key] = json.loads(props[key])
        except (KeyError, ValueError):
            raise GuideError(f"{path}: guide metadata is missing or corrupt") from None
        _check_program(path, meta, program)
        validate_guide_graph(path, session, meta, program)
        guide = cls(session, program, path, meta)
        names = {i.name for i in session.get_inputs()}
        if names != set(guide._empty):
            raise GuideError(f"{path}: guide inputs do not match its metadata")
        guide.site_sessions = _site_sessions(path, list(guide.nets), opts)
        return guide

    def params(self, site: int, features: np.ndarray | None, n: int | None = None) -> np.ndarray:
        """The site network's proposal parameters `(n, n_out)` (float64) for feature rows."""
        net = self.nets[site]
        if features is None:
            if self.uses_features:
                raise GuideError(f"{self.path}: site {site} needs features")
            features = np.zeros((n or 0, net["n_f"]), dtype=np.float32)
        x = np.ascontiguousarray(features, dtype=np.float32)
        if x.ndim != 2 or x.shape[1] != net["n_f"]:
            raise GuideError(f"{self.path}: site {site} expects {net['n_f']} features per row, "
                             f"got shape {x.shape} (features changed since training?)")
        sess = self.site_sessions.get(site)
        if sess is not None:
            (out,) = sess.run(None, {f"f_{site}": x})
        else:  # the whole file: every input must be fed (empty batches run too)
            feeds = dict(self._empty)
            feeds[f"f_{site}"] = x
            (out,) = self.session.run([f"p_{site}"], feeds)
        return out.astype(np.float64)

    def propose(self, site: Site, prior_args: np.ndarray, features: np.ndarray | None,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        if site.index not in self.nets:
            values = dist.prior_sample(site, prior_args, rng)
            return values, dist.prior_logpdf(site, prior_args, values)
        params = self.params(site.index, features, n=len(prior_args))
        return dist.proposal_draw(site, prior_args, params, rng)


def _site_sessions(path: str, sites: list[int], opts: ort.SessionOptions
                   ) -> dict[int, ort.InferenceSession]:
    """One session per site net, cut from the file's graph (a call then runs only that
    net); empty when the `onnx` package is missing or cannot split the file."""
    try:
        import onnx
        import onnx.utils
    except ImportError:
        return {}
    try:
        extractor = onnx.utils.Extractor(onnx.load(path))
        return {s: ort.InferenceSession(
                    extractor.extract_model([f"f_{s}"], [f"p_{s}"]).SerializeToString(),
                    opts, providers=["CPUExecutionProvider"])
                for s in sites}
    except Exception:  # any failure: the whole-file session still works
        return {}


def _check_program(path: str, meta: dict[str, Any], program: Program) -> None:
    """GuideError unless the guide was trained for this grammar."""
    if program.grammar_hash and meta["grammar_hash"] != program.grammar_hash:
        raise GuideError(f"{path}: guide was trained for grammar {meta['grammar']!r} "
                         f"({meta['grammar_hash'][:19]}), not {program.name!r} "
                         f"({program.grammar_hash[:19]})")
    theirs = [tuple(s.get(k) for k in SITE_KEYS) for s in meta["sites"]]
    ours = [tuple(getattr(s, k) for k in SITE_KEYS) for s in program.sites]
    if theirs != ours:
        raise GuideError(f"{path}: guide's site table does not match grammar "
                         f"{program.name!r} ({len(theirs)} vs {len(ours)} sites)")


def format_message(path: str, fmt: Any) -> str:
    """Why a file whose `ngpm_format` is not ONNX_FORMAT cannot be used."""
    name, _, version = str(fmt or "").rpartition("/")
    ours_name, _, ours = ONNX_FORMAT.rpartition("/")
    if fmt and name == ours_name:
        newer = version.isdigit() and int(version) > int(ours)
        return (f"{path}: guide format {fmt} {'is newer than' if newer else 'differs from'} "
                f"the {ONNX_FORMAT} this ngpm reads"
                + (" (upgrade ngpm to use it)" if newer else " (export it again)"))
    return f"{path}: not an ngpm guide (written by `ngpmc export`?)"


def _expected_outputs(site: Site, K: int) -> int:
    """Columns of a site network's output (docs/architecture.md section 5)."""
    if site.kind in ("normal", "uniform"):
        return 3 * K
    return 1 if site.kind == "bernoulli" else int(site.k or 0)


def validate_guide_graph(path: str, session: Any, meta: dict[str, Any],
                         program: Program) -> None:
    """GuideError unless the ONNX graph has, for every site net the metadata lists, the
    input `f_<i>` of shape (n, n_f) and the output `p_<i>` of shape (n, n_out) that the
    metadata and the site's kind call for; so a broken file fails at load, not in a run."""
    try:
        K = int(meta["K"])
        nets = {int(i): dict(n) for i, n in meta["nets"].items()}
    except (TypeError, ValueError, AttributeError):
        raise GuideError(f"{path}: guide metadata is missing or corrupt") from None
    inputs = {i.name: i.shape for i in session.get_inputs()}
    outputs = {o.name: o.shape for o in session.get_outputs()}
    for i, net in sorted(nets.items()):
        if not 0 <= i < len(program.sites):
            raise GuideError(f"{path}: guide has a network for site {i}, but grammar "
                             f"{program.name!r} has {len(program.sites)} sites")
        site = program.sites[i]
        n_f, n_out = net.get("n_f"), net.get("n_out")
        want = _expected_outputs(site, K)
        if n_out != want:
            raise GuideError(f"{path}: site {i} ({site.id}) network gives {n_out} outputs; "
                             f"a {site.kind} site needs {want}")
        for kind, name, have, width in (("input", f"f_{i}", inputs, n_f),
                                        ("output", f"p_{i}", outputs, n_out)):
            shape = have.get(name)
            if shape is None:
                raise GuideError(f"{path}: the ONNX graph has no {kind} {name} for site {i} "
                                 f"({site.id}) that its metadata lists (damaged file?)")
            if len(shape) != 2 or (isinstance(shape[1], int) and shape[1] != width):
                raise GuideError(f"{path}: ONNX {kind} {name} has shape {list(shape)}, "
                                 f"the metadata says (n, {width})")
