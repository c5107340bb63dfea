"""A learned guide: the ONNX file written by `ngpmc export`, run with onnxruntime.

`Guide.load(path, program)` checks that the file is an ngpm guide for this grammar (hash and
site table); `Guide.propose` implements the Proposal protocol (docs/architecture.md section 5):
one onnxruntime call per propose (one small session per site net when the `onnx`
package can split the file), then sampling with distributions.proposal_draw. Sites without a
network (unseen in training) fall back to the prior; they are listed in `Guide.fallback_sites`.

`Guide.propose_round` (proposals.RoundProposal) serves every site waiting in an SMC round:
one onnxruntime call of the whole file for all of their networks (each site's rows fed to
its input, empty batches to the rest), then one proposal_draw per group of sites with the
same kind and parameter layout (the rows of all of them at once).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort
from ngpm_runtime import distributions as dist
from ngpm_runtime.errors import GuideError
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
            raise GuideError(f"{path}: not an ngpm guide (written by `ngpmc export`?)")
        try:
            meta = {k: props[k] for k in ("grammar", "grammar_hash", "K")}
            for key in ("sites", "features", "nets", "training"):
                meta[key] = json.loads(props[key])
        except (KeyError, ValueError):
            raise GuideError(f"{path}: guide metadata is missing or corrupt") from None
        _check_program(path, meta, program)
        guide = cls(session, program, path, meta)
        names = {i.name for i in session.get_inputs()}
        if names != set(guide._empty):
            raise GuideError(f"{path}: guide inputs do not match its metadata")
        guide.site_sessions = _site_sessions(path, list(guide.nets), opts)
        return guide

    def params(self, site: int, features: np.ndarray | None, n: int | None = None) -> np.ndarray:
        """The site network's proposal parameters `(n, n_out)` (float64) for feature rows."""
        x = self._input(site, features, n or 0)
        sess = self.site_sessions.get(site)
        if sess is not None:
            (out,) = sess.run(None, {f"f_{site}": x})
        else:  # the whole file: every input must be fed (empty batches run too)
            feeds = dict(self._empty)
            feeds[f"f_{site}"] = x
            (out,) = self.session.run([f"p_{site}"], feeds)
        return out.astype(np.float64)

    def _input(self, site: int, features: np.ndarray | None, n: int) -> np.ndarray:
        """The float32 feature rows the site's network reads (checked)."""
        net = self.nets[site]
        if features is None:
            if self.uses_features:
                raise GuideError(f"{self.path}: site {site} needs features")
            return np.zeros((n, net["n_f"]), dtype=np.float32)
        x = np.ascontiguousarray(features, dtype=np.float32)
        if x.ndim != 2 or x.shape[1] != net["n_f"]:
            raise GuideError(f"{self.path}: site {site} expects {net['n_f']} features per row, "
                             f"got shape {x.shape} (features changed since training?)")
        return x

    def params_round(self, sites: list[int], features: list[np.ndarray | None],
                     ns: list[int]) -> list[np.ndarray]:
        """`params` of several site networks (distinct sites) with one onnxruntime call."""
        if len(sites) == 1:
            return [self.params(sites[0], features[0], ns[0])]
        feeds = dict(self._empty)
        for s, f, n in zip(sites, features, ns, strict=True):
            feeds[f"f_{s}"] = self._input(s, f, n)
        outs = self.session.run([f"p_{s}" for s in sites], feeds)
        return [o.astype(np.float64) for o in outs]

    def propose_round(self, sites: list[Site], prior_args: list[np.ndarray],
                      features: list[np.ndarray] | None, rng: np.random.Generator
                      ) -> list[tuple[np.ndarray, np.ndarray]]:
        """`propose` for every site waiting in an SMC round (proposals.RoundProposal): one
        network call for all of them, one draw per group of like sites."""
        out: list[Any] = [None] * len(sites)
        net = [j for j, site in enumerate(sites) if site.index in self.nets]
        for j, site in enumerate(sites):
            if site.index not in self.nets:
                out[j] = self.propose(site, prior_args[j], None, rng)
        if not net:
            return out
        params = self.params_round([sites[j].index for j in net],
                                   [None if features is None else features[j] for j in net],
                                   [len(prior_args[j]) for j in net])
        groups: dict[tuple, list[int]] = {}
        for j, p in zip(net, params, strict=True):
            key = (sites[j].kind, p.shape[1], prior_args[j].shape[1])
            groups.setdefault(key, []).append(j)
        by_site = dict(zip(net, params, strict=True))
        for js in groups.values():
            args = [prior_args[j] for j in js]
            if len(js) > 1:
                a = np.concatenate(args)
                if np.isfinite(a).all():  # else per site, for the error naming its site
                    values, log_q = dist.proposal_draw(
                        sites[js[0]], a, np.concatenate([by_site[j] for j in js]), rng)
                    cut = np.cumsum([len(x) for x in args])[:-1]
                    for j, v, q in zip(js, np.split(values, cut), np.split(log_q, cut),
                                       strict=True):
                        out[j] = (v, q)
                    continue
            for j in js:
                out[j] = dist.proposal_draw(sites[j], prior_args[j], by_site[j], rng)
        return out

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
