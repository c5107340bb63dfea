"""A learned guide: the ONNX file written by `ngpmc export`, run with onnxruntime.

`Guide.load(path, program)` checks that the file is an ngpm guide for this grammar (hash and
site table) and, in guide_checks, everything else it reads: the metadata's schema, the
network parameters (finite, in range) and a probe run of every network; a damaged or hostile
file is one GuideError, never a traceback or a silently different proposal.

`Guide.propose` implements the Proposal protocol (docs/architecture.md section 5): the
site's network (see Engines), then sampling with distributions.proposal_draw. Sites without
a network (unseen in training) fall back to the prior; they are listed in
`Guide.fallback_sites`.

`Guide.propose_rows` (proposals.RoundProposal) serves every site waiting in an SMC round
with one compiled call (kernels.guide_round) over the rows of all of them (SMC's
`RoundRows`): networks, tempering, draws, log q and log prior; `Guide.propose_round` does
the same for rows given per site.

Engines (`Guide.engine` says which serves a site): with the `onnx` package (the compiler's
installs), every site net that reads features runs in the compiled kernel (`NumpyNet`, the
"numpy" engine: the file's own weights, read by the names in guide_format, float32 like
onnxruntime); a feature-free net
(feature set `const`), or every net when `Guide.numpy_nets` is emptied, runs in its own
onnxruntime session cut from the file. Without `onnx` (the runtime installed alone) the
whole file runs in one onnxruntime session. The load checks that both engines give the same
outputs on the probe rows; a parameter missing under its name, of the wrong shape, or a
graph that computes something else than the numpy engine is a GuideError naming the file,
the site and the cause, never a silent switch to the other engine.

Settings (`ProposalSettings`, the file's optional `proposal` metadata written by `ngpmc
tune`, or `Guide.load(..., settings=)`): a temperature for choices and one for continuous
values (distributions.temper, in the kernel, applied to every network output, so weights
stay exact) and
the ESS fraction below which guided SMC resamples (`smc` reads it).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields
from itertools import accumulate
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
import onnxruntime as ort

from ngpm_runtime.errors import GuideError, ProgramError
from ngpm_runtime.image.features import N_CONTEXT, N_FAR
from ngpm_runtime.inference import distributions as dist
from ngpm_runtime.inference import guide_checks as checks
from ngpm_runtime.inference.guide_format import (
    NET_PARAMS,
    ONNX_FORMAT,
    input_name,
    output_name,
    param_name,
)
from ngpm_runtime.inference.proposals import RoundRows
from ngpm_runtime.inference.sitekinds import MIXTURE, SIGMOID, SOFTMAX
from ngpm_runtime.program import Program, Site

_NO_ROWS = np.zeros(0)
_NO_ARGS = np.zeros((0, 0))
_NO_OUT = np.zeros((0, 3))
# a network head's number in the kernel (kernels.HEAD_MIXTURE, ...) and a kind with it
_HEADS = {MIXTURE: 0, SIGMOID: 1, SOFTMAX: 2}
_HEAD_KIND = {MIXTURE: 0, SIGMOID: 2, SOFTMAX: 3}
PROPOSAL_KEY = "proposal"  # optional metadata: ProposalSettings as JSON
SITE_KEYS = ("id", "kind", "k")  # what must agree between the guide's and program's sites


@dataclass(frozen=True)
class ProposalSettings:
    """How a guide proposes: temperature (mixtures), choice_temperature (bernoulli and
    categorical sites) and ess_threshold (resample when ESS < this fraction of N; None:
    every step). The defaults are the trained networks as they are."""

    temperature: float = 1.0
    choice_temperature: float = 1.0
    ess_threshold: float | None = None

    def __post_init__(self) -> None:
        for name in ("temperature", "choice_temperature"):
            v = getattr(self, name)
            if not (_is_number(v) and 0.05 <= v <= 20.0):
                raise GuideError(f"{name} must be a number in [0.05, 20], got {checks.show(v)}")
        e = self.ess_threshold
        if e is not None and not (_is_number(e) and 0.0 < e <= 1.0):
            raise GuideError(f"ess_threshold must be in (0, 1] or none, got {checks.show(e)}")

    def to_json(self) -> str:
        return json.dumps(asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> ProposalSettings:
        """The settings `to_json` wrote (GuideError if `text` holds anything else)."""
        try:
            d = json.loads(text)
        except (ValueError, RecursionError):
            raise GuideError("not valid JSON") from None
        names = [f.name for f in fields(cls)]
        if not isinstance(d, dict) or set(d) - set(names):
            raise GuideError(f"want an object of {', '.join(names)}, got {checks.show(d)}")
        return cls(**d)

    def label(self) -> str:
        ess = "none" if self.ess_threshold is None else f"{self.ess_threshold:g}"
        return f"T={self.temperature:g},Tc={self.choice_temperature:g},ess={ess}"


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _file_settings(path: str, text: str) -> ProposalSettings:
    """The settings in a guide file's `proposal` metadata (GuideError naming the cause)."""
    try:
        return ProposalSettings.from_json(text)
    except GuideError as err:
        raise GuideError(f"{path}: guide proposal settings are corrupt ({err})") from None


class Guide:
    """Proposal that runs the per-site networks of one ONNX file."""

    def __init__(
        self,
        session: ort.InferenceSession,
        program: Program,
        path: str,
        meta: dict[str, Any],
        settings: ProposalSettings | None = None,
    ) -> None:
        self.session = session
        self.settings = settings or ProposalSettings()
        self._kinds = {s.index: s.kind for s in program.sites}
        self.program = program
        self.path = path
        self.meta = meta
        self.nets: dict[int, dict[str, Any]] = {int(k): v for k, v in meta["nets"].items()}
        self.feature_set: str = meta["features"]["feature_set"]
        self.uses_features = self.feature_set != "const"
        self.feature_context = "context" in self.feature_set.split("+")
        self.feature_far = "far" in self.feature_set.split("+")
        # the columns past a network's own that a recorded trace's rows may have
        self._unread = (
            ()
            if self.feature_far
            else (N_FAR,)
            if self.feature_context
            else (N_CONTEXT, N_CONTEXT + N_FAR)
        )
        # a 3D guide's window (volume/features.py: its layouts say which); None in 2D
        self.feature_window: str | None = None
        if program.dim == 3:
            from ngpm_runtime.volume.features import window_of

            self.feature_window = window_of(meta["features"]["layouts"])
        self.K = int(meta["K"])
        self.training: dict[str, Any] = meta["training"]
        self.fallback_sites: list[int] = [
            s.index for s in program.sites if s.index not in self.nets
        ]
        self._empty = {
            input_name(i): np.zeros((0, n["n_f"]), dtype=np.float32) for i, n in self.nets.items()
        }
        # one small session per site net when the `onnx` package can split the file
        self.site_sessions: dict[int, ort.InferenceSession] = {}
        # the same nets evaluated by the compiled kernel (every net that reads features,
        # with `onnx`); they answer instead of onnxruntime (set {} to use onnxruntime only)
        self.numpy_nets: dict[int, NumpyNet] = {}
        self._kinds_code = np.array([dist.kind_of(s).code for s in program.sites], np.int64)
        self._n_out = np.zeros(len(program.sites), dtype=np.int64)  # outputs per site net
        for i, net in self.nets.items():
            if 0 <= i < len(self._n_out):
                self._n_out[i] = int(net["n_out"])
        self.widest = int(self._n_out.max(initial=1))
        # the features each site's net reads (-1: no net)
        self._n_f = [
            int(self.nets[s.index]["n_f"]) if s.index in self.nets else -1 for s in program.sites
        ]
        from ngpm_runtime import kernels  # numba loads with the guide (its checks run nets)

        self._k = kernels
        self._mixture = [dist.kind_of(s).head == MIXTURE for s in program.sites]
        self._temps: tuple[ProposalSettings, np.ndarray] | None = None

    @property
    def numpy_nets(self) -> dict[int, NumpyNet]:
        """The site nets the compiled kernel evaluates, by site (assign a new dict to
        change them)."""
        return self._numpy_nets

    @numpy_nets.setter
    def numpy_nets(self, nets: dict[int, NumpyNet]) -> None:
        self._numpy_nets = nets
        self._packed: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def _tables(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The kernel's network table (sites, kernels.NET_COLS), weights and columns."""
        if self._packed is None:
            self._packed = pack_nets(self._numpy_nets, len(self.program.sites))
        return self._packed

    @classmethod
    def load(
        cls, path: str | Path, program: Program, settings: ProposalSettings | None = None
    ) -> Guide:
        """The guide in `path` for `program`, proposing with `settings` (default: the
        file's own, else ProposalSettings()). A damaged, hostile or foreign file raises
        GuideError naming the file and the cause (guide_checks: metadata, parameters and
        a probe run of every network)."""
        path = str(path)
        data = checks.read_guide(path)
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = 1
        opts.inter_op_num_threads = 1
        opts.log_severity_level = 3
        try:  # from the bytes read: the file cannot point onnxruntime at other files
            session = ort.InferenceSession(data, opts, providers=["CPUExecutionProvider"])
            props = session.get_modelmeta().custom_metadata_map
        except Exception:  # onnxruntime raises several types for unreadable files
            raise GuideError(
                f"{path}: not a readable ONNX guide (corrupt or truncated file)"
            ) from None
        if props.get("ngpm_format") != ONNX_FORMAT:
            raise GuideError(format_message(path, props.get("ngpm_format")))
        meta = checks.read_meta(path, props)
        _check_program(path, meta, program)
        validate_guide_graph(path, session, meta, program)
        if settings is None and PROPOSAL_KEY in props:
            settings = _file_settings(path, props[PROPOSAL_KEY])
        guide = cls(session, program, path, meta, settings)
        names = {i.name for i in session.get_inputs()}
        if names != set(guide._empty):
            raise GuideError(f"{path}: guide inputs do not match its metadata")
        model = _onnx_model(path, data)
        consts = None if model is None else checks.check_model(path, model, meta)
        rows = checks.probe_rows(guide.nets)
        probe = guide._probe(rows)
        checks.check_outputs(path, probe, program, guide.K)
        if model is not None and consts is not None:
            guide.site_sessions = _site_sessions(path, model, list(rows), opts)
            guide.numpy_nets = _numpy_nets(guide, consts, rows, probe)
        return guide

    def engine(self, site: int) -> str:
        """What computes the site's proposal parameters: "numpy", "onnxruntime" (the
        site's own session), "onnxruntime (whole file)" or "prior" (no network)."""
        if site not in self.nets:
            return "prior"
        if site in self.numpy_nets:
            return "numpy"
        return "onnxruntime" if site in self.site_sessions else "onnxruntime (whole file)"

    def _probe(self, rows: dict[int, np.ndarray]) -> dict[int, np.ndarray]:
        """Every site network's outputs on `rows`, from the whole file (GuideError naming
        the failure if onnxruntime cannot run them)."""
        if not rows:  # no site networks: nothing to run
            return {}
        quiet = ort.RunOptions()
        quiet.log_severity_level = 4  # the error is reported once, below
        try:
            outs = self.session.run(
                [output_name(i) for i in rows], {input_name(i): x for i, x in rows.items()}, quiet
            )
        except Exception as err:  # onnxruntime's errors for a graph that cannot run
            why = (str(err).strip().splitlines() or [type(err).__name__])[0][:200]
            raise GuideError(
                f"{self.path}: the guide's networks fail on test rows (damaged file?): {why}"
            ) from None
        return dict(zip(rows, outs, strict=True))

    def params(self, site: int, features: np.ndarray | None, n: int | None = None) -> np.ndarray:
        """The site network's proposal parameters `(n, n_out)` (float64) for feature rows."""
        x = self._input(site, features, n or 0)
        if site in self._numpy_nets:
            m = len(x)
            params = np.empty((m, self.nets[site]["n_out"]))
            rows = np.full(m, site, dtype=np.int64)
            self._kernel(x, rows, params, _NO_ARGS, np.zeros(m, np.int64), _NO_OUT)
            return params
        return self._temper(site, self._onnx_params(site, x))

    def _onnx_params(self, site: int, x: np.ndarray) -> np.ndarray:
        """The site network's outputs from onnxruntime (float64, not tempered)."""
        sess = self.site_sessions.get(site)
        if sess is not None:
            (out,) = sess.run(None, {input_name(site): x})
        else:  # the whole file: every input must be fed (empty batches run too)
            feeds = dict(self._empty)
            feeds[input_name(site)] = x
            (out,) = self.session.run([output_name(site)], feeds)
        return np.asarray(out, dtype=np.float64)

    def _kernel(
        self,
        x: np.ndarray,
        site: np.ndarray,
        params: np.ndarray,
        args: np.ndarray,
        n_args: np.ndarray,
        out: np.ndarray,
        u: np.ndarray = _NO_ROWS,
        z: np.ndarray = _NO_ROWS,
    ) -> int:
        """kernels.guide_round over rows at sites `site`: networks (params given for the
        others), tempering and, when `out` has rows, draws (prior arguments args[k,
        :n_args[k]]); fills params (n, widest). Returns the first row with bad prior
        arguments, or -1."""
        nets, w, cols = self._tables()
        return int(
            self._k.guide_round(
                x,
                site,
                nets,
                w,
                cols,
                self._kinds_code,
                self._temperatures(),
                params,
                self._n_out[site],
                args,
                n_args,
                u,
                z,
                out,
            )
        )

    def _temperatures(self) -> np.ndarray:
        """(temperature, choice temperature) of the settings, for the kernel."""
        st = self.settings
        if self._temps is None or self._temps[0] is not st:
            self._temps = (st, np.array([st.temperature, st.choice_temperature]))
        return self._temps[1]

    def _temper(self, site: int, params: np.ndarray) -> np.ndarray:
        st = self.settings
        if st.temperature == 1.0 and st.choice_temperature == 1.0:
            return params
        return dist.temper(self._kinds[site], params, st.temperature, st.choice_temperature)

    def _input(self, site: int, features: np.ndarray | None, n: int) -> np.ndarray:
        """The float32 feature rows the site's network reads (checked)."""
        net = self.nets[site]
        if features is None:
            if self.uses_features:
                raise GuideError(f"{self.path}: site {site} needs features")
            return np.zeros((n, net["n_f"]), dtype=np.float32)
        x = np.ascontiguousarray(features, dtype=np.float32)
        if x.ndim == 2 and x.shape[1] > net["n_f"] and x.shape[1] - net["n_f"] in self._unread:
            x = x[:, : net["n_f"]]  # a recorded trace's row: its last columns are not read
        if x.ndim != 2 or x.shape[1] != net["n_f"]:
            raise GuideError(
                f"{self.path}: site {site} expects {net['n_f']} features per row, "
                f"got shape {x.shape} (features changed since training?)"
            )
        return x

    def _onnx_round(self, sites: list[int], xs: list[np.ndarray]) -> list[np.ndarray]:
        """onnxruntime's outputs (float64, not tempered) of several site networks (distinct
        sites) for their checked rows `xs`: one call per site's own session (onnxruntime's
        cost is per graph node, so one run of the whole file, which also runs every other
        net on an empty batch, costs more: benchmarks/smc.py --nets), or one whole-file call
        when the file could not be split."""
        if self.site_sessions or len(sites) == 1:
            return [self._onnx_params(s, x) for s, x in zip(sites, xs, strict=True)]
        feeds = dict(self._empty)
        for s, x in zip(sites, xs, strict=True):
            feeds[input_name(s)] = x
        outs = self.session.run([output_name(s) for s in sites], feeds)
        return [np.asarray(o, dtype=np.float64) for o in outs]

    def propose_round(
        self,
        sites: list[Site],
        prior_args: list[np.ndarray],
        features: list[np.ndarray] | None,
        rng: np.random.Generator,
    ) -> list[tuple[np.ndarray, ...]]:
        """`propose_rows` for rows given per site (distinct sites, in the order given):
        prior_args[j] and features[j] (checked as `propose`'s) are the rows at sites[j].
        Returns per site (values, log q, log prior)."""
        counts = [len(a) for a in prior_args]
        args_list = [
            np.asarray(a, dtype=np.float64).reshape(m, -1)
            for a, m in zip(prior_args, counts, strict=True)
        ]
        n = sum(counts)
        args = np.zeros((n, max([a.shape[1] for a in args_list] + [0])))
        xs = None
        if features is not None:
            xs = [
                self._input(s.index, f, m) if s.index in self.nets else np.zeros((m, 0), np.float32)
                for s, f, m in zip(sites, features, counts, strict=True)
            ]
        x = None if xs is None else np.zeros((n, max([f.shape[1] for f in xs] + [0])), np.float32)
        pos = 0
        for j, (a, m) in enumerate(zip(args_list, counts, strict=True)):
            args[pos : pos + m, : a.shape[1]] = a
            if x is not None and xs is not None:
                x[pos : pos + m, : xs[j].shape[1]] = xs[j]
            pos += m
        rows = RoundRows(
            list(sites),
            counts,
            np.repeat(np.array([s.index for s in sites], np.int64), counts),
            args,
            np.repeat(np.array([a.shape[1] for a in args_list], np.int64), counts),
            x,
            [] if xs is None else [f.shape[1] for f in xs],
        )
        res = self.propose_rows(rows, rng)
        out: list[tuple[np.ndarray, ...]] = []
        pos = 0
        for m in counts:
            part = res[pos : pos + m]
            out.append((part[:, 0], part[:, 1], part[:, 2]))
            pos += m
        return out

    def propose_rows(self, rows: RoundRows, rng: np.random.Generator) -> np.ndarray:
        """Every site waiting in an SMC round (proposals.RoundProposal): (n, 3) value, log
        q, log prior per row. Sites without a network draw from their prior first, in
        order; the rows of all others are one kernel call (kernels.guide_round: networks,
        or onnxruntime's outputs for the nets it serves, tempering, draws, log q and log
        prior) with one uniform per row, then one standard normal per row when a site is
        a mixture."""
        sites, counts = rows.sites, rows.counts
        res = np.empty((len(rows.site), 3))
        nets = self.nets
        served = [s.index in nets for s in sites]
        site, args, n_args = rows.site, rows.args, rows.n_args
        x = self._round_features(rows, served)
        if False in served:  # the prior's draws first, then the network rows alone
            keep = self._prior_rows(rows, served, res, rng)
            if not len(keep):
                return res
            x, site, args, n_args = x[keep], site[keep], args[keep], n_args[keep]
            sites = [s for s, on in zip(sites, served, strict=True) if on]
            counts = [m for m, on in zip(counts, served, strict=True) if on]
        n = len(site)
        params = np.empty((n, self.widest))
        if len(self._numpy_nets) < len(nets):
            self._onnx_rows(sites, counts, x, params)
        u = rng.random(n)
        z = rng.standard_normal(n) if self.needs_normals(sites) else _NO_ROWS
        out = res if n == len(res) else np.empty((n, 3))
        bad = self._kernel(x, site, params, args, n_args, out, u, z)
        if bad >= 0:
            self.bad_row(sites, counts, args, n_args, bad)
        if out is not res:
            res[keep] = out
        return res

    def round_tables(self, sites: list[Site]) -> tuple[Any, ...] | None:
        """kernels.serve_round's network arguments (net table, weights, columns, site
        kinds, temperatures, outputs per site) when its kernel evaluates the net of every
        site in `sites` from features; else None (propose_rows serves the round)."""
        nets = self._numpy_nets
        if not self.uses_features or any(s.index not in nets for s in sites):
            return None
        table, w, cols = self._tables()
        return (table, w, cols, self._kinds_code, self._temperatures(), self._n_out)

    def needs_normals(self, sites: list[Site]) -> bool:
        """Whether a round's draws at `sites` take a standard normal per row (a mixture)."""
        mixture = self._mixture
        return any(mixture[s.index] for s in sites)

    def check_width(self, site: Site, m: int, width: int) -> None:
        """GuideError when `site`'s feature rows (m of them) are not as wide as its net reads."""
        want = self._n_f[site.index]
        if width != want and want >= 0:
            raise GuideError(
                f"{self.path}: site {site.index} expects {want} features per row, got "
                f"shape ({m}, {width}) (features changed since training?)"
            )

    def bad_row(
        self,
        sites: list[Site],
        counts: list[int],
        args: np.ndarray,
        n_args: np.ndarray,
        bad: int,
    ) -> NoReturn:
        """The error for the round's row `bad`, whose prior arguments its site's prior
        cannot take (the kernel found it): naming the site and the cause."""
        pos = 0
        for s, m in zip(sites, counts, strict=True):
            if pos <= bad < pos + m:
                _bad_args(s, args[pos : pos + m, : n_args[pos]])
            pos += m
        raise ProgramError(f"{self.path}: a round's row {bad} has bad prior arguments")

    def _round_features(self, rows: RoundRows, served: list[bool]) -> np.ndarray:
        """The round's float32 feature rows for the kernel, checked against the width
        each site's network reads (zeros for a guide that reads none)."""
        x = rows.features
        n_f = self._n_f
        if x is None or not self.uses_features:
            on = [s.index for s, ok in zip(rows.sites, served, strict=True) if ok]
            if self.uses_features:
                raise GuideError(f"{self.path}: site {on[0]} needs features")
            width = max([n_f[s] for s in on] + [0])
            return np.zeros((len(rows.site), width), dtype=np.float32)
        for s, m, w in zip(rows.sites, rows.counts, rows.widths, strict=True):
            self.check_width(s, m, w)
        return x

    def _prior_rows(
        self, rows: RoundRows, served: list[bool], res: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray:
        """Draw the rows of the sites without a network from their prior into res (value,
        log q = log prior, log prior), in site order; returns the other rows' indices."""
        keep: list[int] = []
        pos = 0
        for s, m, on in zip(rows.sites, rows.counts, served, strict=True):
            if on:
                keep.extend(range(pos, pos + m))
            else:
                args = np.array(rows.args[pos : pos + m, : rows.n_args[pos]])
                values, log_q = self.propose(s, args, None, rng)
                res[pos : pos + m, 0] = values
                res[pos : pos + m, 1] = log_q
                res[pos : pos + m, 2] = log_q
            pos += m
        return np.array(keep, dtype=np.intp)

    def _onnx_rows(
        self, sites: list[Site], counts: list[int], x: np.ndarray, params: np.ndarray
    ) -> None:
        """params of the rows whose nets onnxruntime serves (the kernel tempers and draws)."""
        starts = [0, *accumulate(counts)]
        onnx = [k for k, s in enumerate(sites) if s.index not in self._numpy_nets]
        if not onnx:
            return
        which = [sites[k].index for k in onnx]
        got = self._onnx_round(
            which,
            [
                np.ascontiguousarray(x[starts[k] : starts[k + 1], : self.nets[s]["n_f"]])
                for k, s in zip(onnx, which, strict=True)
            ],
        )
        for k, o in zip(onnx, got, strict=True):
            params[starts[k] : starts[k + 1], : o.shape[1]] = o

    def propose(
        self,
        site: Site,
        prior_args: np.ndarray,
        features: np.ndarray | None,
        rng: np.random.Generator,
    ) -> tuple[np.ndarray, np.ndarray]:
        if site.index not in self.nets:
            values = dist.prior_sample(site, prior_args, rng)
            return values, dist.prior_logpdf(site, prior_args, values)
        params = self.params(site.index, features, n=len(prior_args))
        return dist.proposal_draw(site, prior_args, params, rng)


def _onnx_model(path: str, data: bytes) -> Any:
    """The file's ONNX model (the `onnx` package's), or None without that package."""
    try:
        import onnx
    except ImportError:
        return None
    try:
        return onnx.load_from_string(data)
    except Exception:  # protobuf's DecodeError and others: the file is damaged
        raise GuideError(f"{path}: not a readable ONNX guide (corrupt or truncated file)") from None


def _site_sessions(
    path: str, model: Any, sites: list[int], opts: ort.SessionOptions
) -> dict[int, ort.InferenceSession]:
    """One onnxruntime session per site net, cut from the file's graph `model` (a call then
    runs only that net); GuideError naming the cause if the graph cannot be cut."""
    import onnx.utils

    try:
        extractor = onnx.utils.Extractor(model)
        return {
            s: ort.InferenceSession(
                extractor.extract_model([input_name(s)], [output_name(s)]).SerializeToString(),
                opts,
                providers=["CPUExecutionProvider"],
            )
            for s in sites
        }
    except Exception as err:  # onnx's and onnxruntime's errors, several types
        why = (str(err).strip().splitlines() or [type(err).__name__])[0][:200]
        raise GuideError(f"{path}: cannot cut the guide into its site networks: {why}") from None


def _numpy_nets(
    guide: Guide,
    consts: dict[str, np.ndarray],
    rows: dict[int, np.ndarray],
    probe: dict[int, np.ndarray],
) -> dict[int, NumpyNet]:
    """A NumpyNet for every site net that reads features, from the parameters `consts` by
    name; GuideError if one is missing or misshapen, or if a net does not give
    onnxruntime's outputs `probe` on the probe `rows`."""
    columns = guide.meta["features"]["columns"]
    out = {}
    for s, meta in sorted(guide.nets.items()):
        if not columns[str(s)]:  # feature-free: a constant row (onnxruntime runs it)
            continue
        site = guide.program.sites[s]
        where = f"{guide.path}: site {s} ({site.id}) network"
        net = NumpyNet.from_params(
            where, s, consts, dist.kind_of(site).head, guide.K, meta["n_f"], meta["n_out"]
        )
        got, want = net(rows[s]), probe[s].astype(np.float64)
        if not np.allclose(got, want, rtol=1e-4, atol=1e-5):
            worst = float(np.max(np.abs(got - want)))
            raise GuideError(
                f"{where}: its graph does not compute what `ngpmc export` "
                f"writes (the numpy engine and onnxruntime differ by "
                f"{worst:.3g} on test rows; edited file?)"
            )
        out[s] = net
    return out


class NumpyNet:
    """One site network evaluated by the compiled kernel (kernels.guide_round; the name is
    the engine's, "numpy", from before the kernel), float32 like onnxruntime, from the
    parameters of the ONNX file, read by name (guide_format): `tanh(x[:, cols] @ w1' +
    b1)`, then `bounds * tanh(h @ w2' + b2)`, then the site kind's head (sitekinds:
    log-softmax over the first K mixture columns, sigmoid or softmax): the graph
    ngpm_compiler/learning/export.py writes.

    Why: SMC's batches are small, and there onnxruntime's per-call overhead dominates
    (benchmarks/smc.py --nets prints both, from 1 to 1000 rows); one engine for every batch
    size keeps a particle's proposal independent of how many particles share its round. A
    guided round runs every site's net in one kernel call with the draws (`Guide` packs
    them: `pack_nets`). Guide.load checks it against onnxruntime on the probe rows;
    tests/runtime/inference/test_guide.py on many more, to 1e-5; tests/reference/guide.py
    keeps the numpy code it replaced."""

    def __init__(
        self,
        n_f: int,
        cols: np.ndarray,
        w1: np.ndarray,
        b1: np.ndarray,
        w2: np.ndarray,
        b2: np.ndarray,
        bounds: np.ndarray,
        head: str,
        k: int,
    ) -> None:
        cols = cols.astype(np.intp)
        # every column in order (the usual case): no gather
        self.cols = None if np.array_equal(cols, np.arange(n_f)) else cols
        self.w1t = np.ascontiguousarray(w1.T, dtype=np.float32)
        self.b1 = b1.astype(np.float32)
        self.w2t = np.ascontiguousarray(w2.T, dtype=np.float32)
        self.b2 = b2.astype(np.float32)
        self.bounds = bounds.astype(np.float32)
        self.head = head
        self.k = k

    @classmethod
    def from_params(
        cls,
        where: str,
        site: int,
        consts: dict[str, np.ndarray],
        head: str,
        K: int,
        n_f: int,
        n_out: int,
    ) -> NumpyNet:
        """Site `site`'s network from the file's parameters `consts` (name -> array), for a
        kind with `head`; GuideError (starting with `where`) for a parameter missing under
        its name or of another shape than the export writes."""
        names = [param_name(site, role) for role in NET_PARAMS]
        missing = [name for name in names if name not in consts]
        if missing:
            raise GuideError(f"{where} has no parameter {missing[0]} (renamed or damaged file?)")
        cols, w1, b1, w2, b2, bounds = (consts[name] for name in names)
        hidden = w1.shape[0] if w1.ndim == 2 else -1
        want = {
            names[0]: (len(cols),),
            names[1]: (hidden, len(cols)),
            names[2]: (hidden,),
            names[3]: (n_out, hidden),
            names[4]: (n_out,),
            names[5]: (n_out,),
        }
        for name, a in zip(names, (cols, w1, b1, w2, b2, bounds), strict=True):
            dtype = np.int64 if name == names[0] else np.float32
            if a.shape != want[name] or a.dtype != dtype or hidden < 1:
                raise GuideError(
                    f"{where}: parameter {name} is {a.dtype} of shape "
                    f"{list(a.shape)}, not the export's (damaged file?)"
                )
        if cols.min(initial=0) < 0 or cols.max(initial=0) >= n_f:
            raise GuideError(
                f"{where}: parameter {names[0]} reads columns outside the "
                f"{n_f} features (damaged file?)"
            )
        return cls(n_f, cols, w1, b1, w2, b2, bounds, head, K if head == MIXTURE else 0)

    def packed(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """This net for kernels.guide_round: its row of the network table (offsets from 0),
        its float32 weights (w1', b1, w2', b2, bounds) and its input columns."""
        from ngpm_runtime import kernels

        n_in, hid = self.w1t.shape
        n_out = self.w2t.shape[1]
        w = np.concatenate(
            [self.w1t.reshape(-1), self.b1, self.w2t.reshape(-1), self.b2, self.bounds]
        ).astype(np.float32)
        row = np.zeros(kernels.NET_COLS, dtype=np.int64)
        row[: kernels.NET_W1] = (1, n_in, hid, n_out, _HEADS[self.head], self.k)
        at = np.cumsum([0, n_in * hid, hid, hid * n_out, n_out])
        row[kernels.NET_W1 : kernels.NET_COLS_AT] = at
        cols = np.arange(n_in) if self.cols is None else self.cols
        return row, w, cols.astype(np.int64)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """(n, n_out) float64 proposal parameters for float32 feature rows (n, n_f)."""
        from ngpm_runtime import kernels

        nets, w, cols = pack_nets({0: self}, 1)
        x = np.ascontiguousarray(x, dtype=np.float32)
        n = len(x)
        out = np.empty((n, self.w2t.shape[1]))
        kernels.guide_round(
            x,
            np.zeros(n, dtype=np.int64),
            nets,
            w,
            cols,
            np.array([_HEAD_KIND[self.head]], dtype=np.int64),
            np.ones(2),
            out,
            np.full(n, out.shape[1], dtype=np.int64),
            _NO_ARGS,
            np.zeros(n, dtype=np.int64),
            _NO_ROWS,
            _NO_ROWS,
            _NO_OUT,
        )
        return out


def pack_nets(nets: dict[int, NumpyNet], n_sites: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """kernels.guide_round's network table (n_sites, kernels.NET_COLS) for the site nets
    `nets` (a site without one: a row of zeros), all weights in one float32 array and
    all input columns in one int64 array."""
    from ngpm_runtime import kernels

    table = np.zeros((n_sites, kernels.NET_COLS), dtype=np.int64)
    ws, cs = [], []
    at_w = at_c = 0
    for site, net in sorted(nets.items()):
        row, w, cols = net.packed()
        row[kernels.NET_W1 : kernels.NET_COLS_AT] += at_w
        row[kernels.NET_COLS_AT] = at_c
        table[site] = row
        ws.append(w)
        cs.append(cols)
        at_w += len(w)
        at_c += len(cols)
    w_all = np.concatenate(ws) if ws else np.zeros(0, dtype=np.float32)
    c_all = np.concatenate(cs) if cs else np.zeros(0, dtype=np.int64)
    return table, w_all, c_all


def _bad_args(site: Site, args: np.ndarray) -> NoReturn:
    """The ProgramError for prior arguments the site's prior cannot take."""
    dist.prior_logpdf(site, args, np.zeros(len(args)))  # raises the error naming the cause
    raise ProgramError(
        f"site {site.id} (line {site.line}): prior arguments a {site.kind} prior cannot take"
    )


def _check_program(path: str, meta: dict[str, Any], program: Program) -> None:
    """GuideError unless the guide was trained for this grammar."""
    if program.grammar_hash and meta["grammar_hash"] != program.grammar_hash:
        raise GuideError(
            f"{path}: guide was trained for grammar {meta['grammar']!r} "
            f"({meta['grammar_hash'][:19]}), not {program.name!r} "
            f"({program.grammar_hash[:19]})"
        )
    theirs = [tuple(s.get(k) for k in SITE_KEYS) for s in meta["sites"]]
    ours = [tuple(getattr(s, k) for k in SITE_KEYS) for s in program.sites]
    if theirs != ours:
        raise GuideError(
            f"{path}: guide's site table does not match grammar "
            f"{program.name!r} ({len(theirs)} vs {len(ours)} sites)"
        )
    if program.dim == 3:
        from ngpm_runtime.volume.features import check_guide_layouts

        check_guide_layouts(path, meta, program)


def format_message(path: str, fmt: object) -> str:
    """Why a file whose `ngpm_format` is not ONNX_FORMAT cannot be used."""
    name, _, version = str(fmt or "").rpartition("/")
    ours_name, _, ours = ONNX_FORMAT.rpartition("/")
    if fmt and name == ours_name:
        newer = version.isdigit() and int(version) > int(ours)
        return (
            f"{path}: guide format {fmt} {'is newer than' if newer else 'differs from'} "
            f"the {ONNX_FORMAT} this ngpm reads"
            + (" (upgrade ngpm to use it)" if newer else " (export it again)")
        )
    return f"{path}: not an ngpm guide (written by `ngpmc export`?)"


def validate_guide_graph(
    path: str, session: ort.InferenceSession, meta: dict[str, Any], program: Program
) -> None:
    """GuideError unless the ONNX graph has, for every site net the metadata lists, the
    input `f_<i>` of shape (n, n_f) and the output `p_<i>` of shape (n, n_out) that the
    metadata and the site's kind call for; so a broken file fails at load, not in a run.
    `meta` is guide_checks.read_meta's."""
    K = int(meta["K"])
    nets = {int(i): n for i, n in meta["nets"].items()}
    inputs = {i.name: i.shape for i in session.get_inputs()}
    outputs = {o.name: o.shape for o in session.get_outputs()}
    for i, net in sorted(nets.items()):
        if not 0 <= i < len(program.sites):
            raise GuideError(
                f"{path}: guide has a network for site {i}, but grammar "
                f"{program.name!r} has {len(program.sites)} sites"
            )
        site = program.sites[i]
        if net["kind"] != site.kind:
            raise GuideError(
                f"{path}: site {i} ({site.id}) network is for a {net['kind']!r} "
                f"site; the grammar's is {site.kind!r}"
            )
        n_f, n_out = net["n_f"], net["n_out"]
        want = checks.expected_outputs(site, K)
        if n_out != want:
            raise GuideError(
                f"{path}: site {i} ({site.id}) network gives {n_out} outputs; "
                f"a {site.kind} site needs {want}"
            )
        for kind, name, have, width in (
            ("input", input_name(i), inputs, n_f),
            ("output", output_name(i), outputs, n_out),
        ):
            shape = have.get(name)
            if shape is None:
                raise GuideError(
                    f"{path}: the ONNX graph has no {kind} {name} for site {i} "
                    f"({site.id}) that its metadata lists (damaged file?)"
                )
            if len(shape) != 2 or (isinstance(shape[1], int) and shape[1] != width):
                raise GuideError(
                    f"{path}: ONNX {kind} {name} has shape {list(shape)}, "
                    f"the metadata says (n, {width})"
                )
