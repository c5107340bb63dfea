"""The compiled deriver's generic kernels (inference/compiled_run.py): a step's rounds in
one call (prior_derive, guided_derive: the grammar's `advance`, called by address through
native_call, a round's outcomes, SiteOrder's site choice, the run's draws, the prior's
values or a guided round's packing and serving (kernels.serve_round)), a replay's weights,
resampling of the particles' arrays, and the linked rows of their primitives and traces.
Grammar-independent, so compiled once and cached (the grammar's own kernel,
geometry/compiled.py, is the derivation loop only). Each does what run._Run does in
Python, in the same order, so seeded runs are bit-identical to it.
"""

from __future__ import annotations

import numpy as np

from ngpm_runtime.geometry.compiled import GROW
from ngpm_runtime.geometry.derive import DONE, DRAWN, NEED
from ngpm_runtime.kernel_cache import drop_stale_cache
from ngpm_runtime.kernels import (
    LOG_2PI,
    _memo_width,
    _pairwise_sum,
    _prior_lp,
    add_weights,
    ancestors,
    circuit_increment,
    draw,
    jit,
    serve_round,
    shape_increment,
    take_rows,
)
from ngpm_runtime.native_call import call_native, generator_at


@jit
def chain_rows(head: np.ndarray, prev: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rows of lists kept as linked rows (compiled_run._Pool: `head[i]` particle i's
    newest row, `prev[r]` the row before r, -1 none): every list's rows oldest first, one
    list after the other, and where each starts (n + 1,)."""
    n = head.shape[0]
    starts = np.zeros(n + 1, dtype=np.int64)
    pos = 0
    for i in range(n):
        starts[i] = pos
        r = head[i]
        while r >= 0:
            pos += 1
            r = prev[r]
    starts[n] = pos
    out = np.empty(pos, dtype=np.int64)
    for i in range(n):
        r = head[i]
        j = starts[i + 1] - 1
        while r >= 0:
            out[j] = r
            j -= 1
            r = prev[r]
    return out, starts


@jit
def link_rows(head: np.ndarray, prev: np.ndarray, top: int, ids: np.ndarray) -> None:
    """Rows top, top + 1, ... become the newest of lists ids[0], ids[1], ... in turn
    (compiled_run._Pool; a list may get several)."""
    for r in range(ids.shape[0]):
        i = ids[r]
        prev[top + r] = head[i]
        head[i] = top + r


@jit
def _saw(reach: np.ndarray, a: int, b: int) -> None:
    """SiteOrder.saw: site b was asked for right after site a (reach: its closure)."""
    if reach[a, b]:
        return
    new = reach[b].copy()
    new[b] = True
    for x in range(reach.shape[0]):
        if x == a or reach[x, a]:
            for y in range(reach.shape[1]):
                if new[y]:
                    reach[x, y] = True


@jit
def _pick(reach: np.ndarray, wait_n: np.ndarray) -> int:
    """SiteOrder.pick: a waiting site no other waiting site leads to, most particles
    first, the lowest index on ties (-1: none waits)."""
    m = wait_n.shape[0]
    n_wait = 0
    only = -1
    for s in range(m):
        if wait_n[s] > 0:
            n_wait += 1
            only = s
    if n_wait <= 1:
        return only
    blocked = np.zeros(m, dtype=np.bool_)
    for a in range(m):
        if wait_n[a] > 0:
            for b in range(m):
                if b != a and wait_n[b] > 0 and reach[a, b]:
                    blocked[b] = True
    free = False
    for s in range(m):
        if wait_n[s] > 0 and not blocked[s]:
            free = True
    best = -1
    for s in range(m):
        if wait_n[s] > 0 and (not blocked[s] or not free):
            if best < 0 or wait_n[s] > wait_n[best]:
                best = s
    return best


@jit
def _fsum(a: np.ndarray) -> float:
    """math.fsum (Shewchuk's exact partial sums)."""
    partials = np.zeros(a.shape[0] + 1)
    m = 0
    for x in a:
        i = 0
        for j in range(m):
            y = partials[j]
            if abs(x) < abs(y):
                x, y = y, x
            hi = x + y
            lo = y - (hi - x)
            if lo != 0.0:
                partials[i] = lo
                i += 1
            x = hi
        partials[i] = x
        m = i + 1
    total = 0.0
    for j in range(m):
        total += partials[j]
    return total


@jit
def _prior_draw(
    kind: int, args: np.ndarray, d: np.ndarray, out_v: np.ndarray, out_lp: np.ndarray
) -> None:
    """sitekinds' prior_draw for the rows of `args` (one site): the same generator call,
    the same values and log prior (numpy's arithmetic in numpy's order)."""
    n, k = args.shape
    if kind == 0:  # normal
        z = d
        point = False
        for r in range(n):
            sd = abs(args[r, 1])
            out_v[r] = args[r, 0] + sd * z[r]
            if not sd > 0:
                point = True
        for r in range(n):
            sd = abs(args[r, 1])
            if not point:
                out_lp[r] = -0.5 * z[r] * z[r] - np.log(sd) - 0.5 * LOG_2PI
            elif sd == 0:
                out_lp[r] = 0.0 if out_v[r] == args[r, 0] else -np.inf
            else:
                zz = (out_v[r] - args[r, 0]) / sd
                lp = -0.5 * zz * zz - np.log(sd) - 0.5 * LOG_2PI
                out_lp[r] = lp if lp == lp else -np.inf
    elif kind == 1:  # uniform
        u = d
        for r in range(n):
            a = min(args[r, 0], args[r, 1])
            b = max(args[r, 0], args[r, 1])
            width = b - a
            out_v[r] = a + width * u[r]
            out_lp[r] = -np.log(width if width > 0 else 1.0)
    elif kind == 2:  # bernoulli
        u = d
        for r in range(n):
            p = min(max(args[r, 0], 0.0), 1.0)
            if u[r] < p:
                out_v[r] = 1.0
                out_lp[r] = np.log(p)
            else:
                out_v[r] = 0.0
                out_lp[r] = np.log(1.0 - p)
    else:
        _categorical_draw(args, d, out_v, out_lp)


@jit
def _categorical_draw(
    args: np.ndarray, u: np.ndarray, out_v: np.ndarray, out_lp: np.ndarray
) -> None:
    """_prior_draw of a categorical site (sitekinds.Categorical.prior_draw)."""
    n, k = args.shape
    same = n > 1
    for r in range(1, n):
        for j in range(k):
            if args[r, j] != args[0, j]:
                same = False
    if same:  # one distribution for every row (a stochastic group)
        cum = np.empty(k)
        c = 0.0
        for j in range(k):
            c += args[0, j]
            cum[j] = c
        total = _fsum(args[0])
        for r in range(n):
            x = u[r] * cum[k - 1]
            j = 0
            while j < k and cum[j] <= x:
                j += 1
            j = min(j, k - 1)
            out_v[r] = j
            out_lp[r] = np.log(args[0, j] / total)
    else:
        p = np.empty((n, k))
        for r in range(n):
            total = _pairwise_sum(args[r])
            for j in range(k):
                p[r, j] = args[r, j] / total
        cum = np.empty(k)
        for r in range(n):
            c = 0.0
            for j in range(k):
                c += p[r, j]
                cum[j] = c
            x = u[r] * cum[k - 1]
            j = 0
            for i in range(k):
                if cum[i] <= x:
                    j += 1
            j = min(j, k - 1)
            out_v[r] = j
            out_lp[r] = np.log(p[r, j])


@jit
def sort_outcomes(
    group: np.ndarray,
    codes: np.ndarray,
    served: np.ndarray,
    need: np.ndarray,
    n_prims: np.ndarray,
    wait_ids: np.ndarray,
    wait_n: np.ndarray,
    drawn: np.ndarray,
    empty: np.ndarray,
    counts: np.ndarray,
    status: np.ndarray,
    limit: np.ndarray,
    reach: np.ndarray,
) -> None:
    """A round's outcomes (run._Run._derive): particles group[j] (served at site
    served[j], -1 none) that drew into drawn (counts[0]), those that ask for a value into
    the waiting lists (SiteOrder.saw: their site follows the one they were served), those
    that ended into status (1 done, 2 limit: max modules) and, without a primitive, into
    empty (counts[1])."""
    m = wait_n.shape[0]
    asked = np.zeros((m, m), dtype=np.bool_)
    for j in range(group.shape[0]):
        i = group[j]
        code = codes[j]
        if code == DRAWN:
            drawn[counts[0]] = i
            counts[0] += 1
        elif code == NEED:
            s = int(need[i, 0])
            if served[j] >= 0:
                asked[served[j], s] = True
            wait_ids[s, wait_n[s]] = i
            wait_n[s] += 1
        else:
            status[i] = 1 if code == DONE else 2
            if code != DONE:
                limit[i] = 1
            if n_prims[i] == 0:
                empty[counts[1]] = i
                counts[1] += 1
    for a in range(m):
        for s in range(m):
            if asked[a, s]:
                _saw(reach, a, s)


@jit
def free_sites(reach: np.ndarray, wait_n: np.ndarray) -> np.ndarray:
    """SiteOrder.free: every waiting site no other waiting site leads to, ascending, or
    [pick] when a cycle leaves none (empty: none waits)."""
    m = wait_n.shape[0]
    out = np.empty(m, dtype=np.int64)
    n = 0
    for s in range(m):
        if wait_n[s] > 0:
            blocked = False
            for a in range(m):
                if a != s and wait_n[a] > 0 and reach[a, s]:
                    blocked = True
            if not blocked:
                out[n] = s
                n += 1
    if n == 0:
        a = _pick(reach, wait_n)
        if a >= 0:
            out[0] = a
            n = 1
    return out[:n]


@jit
def pack_waiting(
    sites: np.ndarray,
    wait_ids: np.ndarray,
    wait_n: np.ndarray,
    stack: np.ndarray,
    sp: np.ndarray,
    turtle: np.ndarray,
    n_turtle: int,
    need: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The waiting particles of `sites` as run._Run._pack packs them (unpack_round's
    layout, each site's particles ascending; the waiting module is on top of a particle's
    stack), taken out of the waiting lists; and the particles in row order."""
    size = 0
    rows = 0
    for s in sites:
        m = wait_n[s]
        i = wait_ids[s, 0]
        a = int(stack[i, sp[i] - 1, 2])
        k = int(need[i, 1])
        size += 4 + m * (2 + n_turtle + a + k)
        rows += m
    flat = np.empty(size)
    order = np.empty(rows, dtype=np.int64)
    pos = 0
    r = 0
    for s in sites:
        m = wait_n[s]
        group = np.sort(wait_ids[s, :m])
        wait_n[s] = 0
        top = stack[group[0], sp[group[0]] - 1]
        a = int(top[2])
        k = int(need[group[0], 1])
        flat[pos] = s
        flat[pos + 1] = m
        flat[pos + 2] = a
        flat[pos + 3] = k
        pos += 4
        for i in group:
            row = stack[i, sp[i] - 1]
            if int(row[2]) != a or int(need[i, 1]) != k:
                raise ValueError("modules of different arity share a site")
            order[r] = i
            r += 1
            flat[pos] = i
            flat[pos + 1] = row[1]
            pos += 2
            for q in range(n_turtle):
                flat[pos + q] = turtle[i, q]
            pos += n_turtle
            for q in range(a):
                flat[pos + q] = row[3 + q]
            pos += a
            for q in range(k):
                flat[pos + q] = need[i, 2 + q]
            pos += k
    return flat, order


@jit
def take_values(
    order: np.ndarray, values: np.ndarray, vals: np.ndarray, nv: np.ndarray, need: np.ndarray
) -> np.ndarray:
    """Particles order[r] drew values[r]: appended to their replay values (vals grows when
    full: returned), their requests served."""
    top = 0
    for i in order:
        top = max(top, nv[i])
    if top >= vals.shape[1]:
        more = np.zeros((vals.shape[0], 2 * vals.shape[1]))
        more[:, : vals.shape[1]] = vals
        vals = more
    for r in range(order.shape[0]):
        i = order[r]
        vals[i, nv[i]] = values[r]
        nv[i] += 1
        need[i, 0] = -1.0
    return vals


@jit
def guided_round(
    group: np.ndarray,
    codes: np.ndarray,
    served: np.ndarray,
    need: np.ndarray,
    n_prims: np.ndarray,
    wait_ids: np.ndarray,
    wait_n: np.ndarray,
    drawn: np.ndarray,
    empty: np.ndarray,
    counts: np.ndarray,
    status: np.ndarray,
    limit: np.ndarray,
    reach: np.ndarray,
    stack: np.ndarray,
    sp: np.ndarray,
    turtle: np.ndarray,
    n_turtle: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A guided round's bookkeeping before kernels.serve_round, in one call: the outcomes
    of advancing `group` (sort_outcomes), the free waiting sites (free_sites) and their
    particles packed (pack_waiting). Returns the packed state, the particles in row
    order, the sites, their particle counts and the site of each row (empty arrays: the
    step is over)."""
    sort_outcomes(
        group,
        codes,
        served,
        need,
        n_prims,
        wait_ids,
        wait_n,
        drawn,
        empty,
        counts,
        status,
        limit,
        reach,
    )
    sites = free_sites(reach, wait_n)
    sizes = np.empty(sites.shape[0], dtype=np.int64)
    for j in range(sites.shape[0]):
        sizes[j] = wait_n[sites[j]]
    flat, rows = pack_waiting(sites, wait_ids, wait_n, stack, sp, turtle, n_turtle, need)
    row_site = np.empty(rows.shape[0], dtype=np.int64)
    r = 0
    for j in range(sites.shape[0]):
        for _ in range(sizes[j]):
            row_site[r] = sites[j]
            r += 1
    return flat, rows, sites, sizes, row_site


@jit
def serve_take(
    flat: np.ndarray,
    n_turtle: int,
    shape: np.ndarray,
    idx: np.ndarray,
    site: np.ndarray,
    rows_turtle: np.ndarray,
    depth: np.ndarray,
    extra: np.ndarray,
    n_extra: np.ndarray,
    args: np.ndarray,
    n_args: np.ndarray,
    x: np.ndarray,
    view: np.ndarray,
    size: np.ndarray,
    offs: np.ndarray,
    target: np.ndarray,
    canvas: np.ndarray,
    ctx: np.ndarray,
    ctx_geom: np.ndarray,
    cells: np.ndarray,
    cell_t: np.ndarray,
    table: np.ndarray,
    w: np.ndarray,
    cols: np.ndarray,
    kinds: np.ndarray,
    temps: np.ndarray,
    n_out: np.ndarray,
    params: np.ndarray,
    u: np.ndarray,
    z: np.ndarray,
    out: np.ndarray,
    log_w: np.ndarray,
    log_prior: np.ndarray,
    order: np.ndarray,
    vals: np.ndarray,
    nv: np.ndarray,
    need: np.ndarray,
    memo: np.ndarray,
    memo_key: np.ndarray,
) -> tuple[int, int, np.ndarray]:
    """serve_round for the compiled deriver's round (the rows packed by guided_round for
    particles `order`), then their values into the replay values (take_values) unless a
    row's prior arguments are bad. Returns (row count, first bad row or -1, vals: grown
    when full). Long because it takes serve_round's arguments one by one (numba types
    flat arguments fast, tuples slowly)."""
    n, bad = serve_round(
        flat,
        n_turtle,
        shape,
        idx,
        site,
        rows_turtle,
        depth,
        extra,
        n_extra,
        args,
        n_args,
        x,
        view,
        size,
        offs,
        target,
        canvas,
        ctx,
        ctx_geom,
        cells,
        cell_t,
        table,
        w,
        cols,
        kinds,
        temps,
        n_out,
        params,
        u,
        z,
        out,
        log_w,
        log_prior,
        memo,
        memo_key,
    )
    if bad < 0:
        vals = take_values(order, out[:n, 0], vals, nv, need)
    return n, bad, vals


@jit
def take_particles(
    anc: np.ndarray,
    stack: np.ndarray,
    sp: np.ndarray,
    turtle: np.ndarray,
    tstack: np.ndarray,
    tsp: np.ndarray,
    vals: np.ndarray,
    nv: np.ndarray,
    need: np.ndarray,
    n_prims: np.ndarray,
    work: np.ndarray,
    o_stack: np.ndarray,
    o_sp: np.ndarray,
    o_turtle: np.ndarray,
    o_tstack: np.ndarray,
    o_tsp: np.ndarray,
    o_vals: np.ndarray,
    o_nv: np.ndarray,
    o_need: np.ndarray,
    o_n_prims: np.ndarray,
    o_work: np.ndarray,
) -> None:
    """Resampling of the compiled deriver's particles (compiled_run.py): row k of each o_
    array becomes row anc[k] of its array (of the stacks and replay values, the rows in use
    only)."""
    w_stack, w_tstack, w_turtle, w_need = (
        stack.shape[2],
        tstack.shape[2],
        turtle.shape[1],
        need.shape[1],
    )
    for k in range(anc.shape[0]):  # loops, not slices: rows of a few numbers
        a = anc[k]
        o_sp[k] = sp[a]
        o_tsp[k] = tsp[a]
        o_nv[k] = nv[a]
        o_n_prims[k] = n_prims[a]
        o_work[k] = work[a]
        for j in range(sp[a]):
            for c in range(w_stack):
                o_stack[k, j, c] = stack[a, j, c]
        for j in range(tsp[a]):
            for c in range(w_tstack):
                o_tstack[k, j, c] = tstack[a, j, c]
        for j in range(nv[a]):
            o_vals[k, j] = vals[a, j]
        for c in range(w_turtle):
            o_turtle[k, c] = turtle[a, c]
        for c in range(w_need):
            o_need[k, c] = need[a, c]


@jit
def resample_rows(
    counts: np.ndarray,
    cum: np.ndarray,
    u: np.ndarray,
    live: np.ndarray,
    status: np.ndarray,
    limit: np.ndarray,
    log_prior: np.ndarray,
    log_lik: np.ndarray,
    o_status: np.ndarray,
    o_limit: np.ndarray,
    o_log_prior: np.ndarray,
    o_log_lik: np.ndarray,
    image: np.ndarray,
    padded: np.ndarray,
    o_image: np.ndarray,
    o_padded: np.ndarray,
    stack: np.ndarray,
    sp: np.ndarray,
    turtle: np.ndarray,
    tstack: np.ndarray,
    tsp: np.ndarray,
    vals: np.ndarray,
    nv: np.ndarray,
    need: np.ndarray,
    n_prims: np.ndarray,
    work: np.ndarray,
    o_stack: np.ndarray,
    o_sp: np.ndarray,
    o_turtle: np.ndarray,
    o_tstack: np.ndarray,
    o_tsp: np.ndarray,
    o_vals: np.ndarray,
    o_nv: np.ndarray,
    o_need: np.ndarray,
    o_n_prims: np.ndarray,
    o_work: np.ndarray,
) -> tuple[np.ndarray, int]:
    """A compiled run's resampling in one call: the ancestors (kernels.ancestors of
    resample.ancestor_counts' copies, cumulative sum and draws u), then row k of every o_
    array becomes row anc[k] of its array: the population's status, limit, log prior and
    log likelihood, the canvases and pyramids (kernels.take_rows; no rows: no canvas) and
    the deriver's state (take_particles). The particles still live (status 0) into live.
    Returns (the ancestors, how many are live)."""
    anc = ancestors(counts, cum, u)
    n_live = 0
    for k in range(anc.shape[0]):
        a = anc[k]
        o_status[k] = status[a]
        o_limit[k] = limit[a]
        o_log_prior[k] = log_prior[a]
        o_log_lik[k] = log_lik[a]
        if o_status[k] == 0:
            live[n_live] = k
            n_live += 1
    if image.shape[0]:
        take_rows(image, padded, anc, o_image, o_padded)
    take_particles(
        anc, stack, sp, turtle, tstack, tsp, vals, nv, need, n_prims, work, o_stack, o_sp,
        o_turtle, o_tstack, o_tsp, o_vals, o_nv, o_need, o_n_prims, o_work,
    )  # fmt: skip
    return anc, n_live


@jit
def start_rounds(
    live: np.ndarray, need: np.ndarray, wait_ids: np.ndarray, wait_n: np.ndarray
) -> np.ndarray:
    """A step's first round (run._Run._derive): the live particles not waiting (to
    advance); the waiting ones into wait_ids[site, :wait_n[site]]."""
    group = np.empty(live.shape[0], dtype=np.int64)
    g = 0
    wait_n[:] = 0
    for i in live:
        s = int(need[i, 0])
        if s < 0:
            group[g] = i
            g += 1
        else:
            wait_ids[s, wait_n[s]] = i
            wait_n[s] += 1
    return group[:g]


@jit
def prior_pick(
    group: np.ndarray,
    codes: np.ndarray,
    served: int,
    need: np.ndarray,
    n_prims: np.ndarray,
    wait_ids: np.ndarray,
    wait_n: np.ndarray,
    drawn: np.ndarray,
    empty: np.ndarray,
    counts: np.ndarray,
    status: np.ndarray,
    limit: np.ndarray,
    reach: np.ndarray,
) -> tuple[int, int]:
    """A round of run._Run._derive for the prior proposal, after the compiled deriver
    advanced `group` (outcomes `codes`; `served` the site its particles were served, -1 in
    a step's first round): the outcomes sorted (sort_outcomes) and SiteOrder's next site.
    Returns (the site, its waiting particles; -1, 0: the step is over); the caller draws
    the site's prior values and calls prior_serve."""
    served_of = np.full(group.shape[0], served, dtype=np.int64)
    sort_outcomes(
        group,
        codes,
        served_of,
        need,
        n_prims,
        wait_ids,
        wait_n,
        drawn,
        empty,
        counts,
        status,
        limit,
        reach,
    )
    a = _pick(reach, wait_n)
    return (a, wait_n[a]) if a >= 0 else (-1, 0)


@jit
def prior_serve(
    a: int,
    d: np.ndarray,
    need: np.ndarray,
    wait_ids: np.ndarray,
    wait_n: np.ndarray,
    counts: np.ndarray,
    site_kind: np.ndarray,
    log_prior: np.ndarray,
    vals: np.ndarray,
    nv: np.ndarray,
    rec: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """prior_pick's site a served: its waiting particles (ascending, taken out of the
    list) get sitekinds' prior_draw values from the draws `d` (the run's standard normals
    or uniforms, one per particle), their log prior added, the values appended for replay
    and, when rec has columns, to rec as (particle, site, value) rows (counts[2]). Returns
    the served particles (to advance next), vals and rec (new arrays when they grew)."""
    m = wait_n[a]
    nxt = np.sort(wait_ids[a, :m])
    wait_n[a] = 0
    k = int(need[nxt[0], 1])
    args = np.empty((m, k))
    for r in range(m):
        for j in range(k):
            args[r, j] = need[nxt[r], 2 + j]
    v = np.empty(m)
    lp = np.empty(m)
    _prior_draw(site_kind[a], args, d, v, lp)
    for r in range(m):
        log_prior[nxt[r]] += lp[r]
    vals = take_values(nxt, v, vals, nv, need)
    rec = _record(rec, counts, nxt, np.full(m, a, dtype=np.int64), v)
    return nxt, vals, rec


@jit
def _record(
    rec: np.ndarray, counts: np.ndarray, ids: np.ndarray, sites: np.ndarray, values: np.ndarray
) -> np.ndarray:
    """Rows (ids[r], sites[r], values[r]) appended to the recorded values rec (counts[2]
    rows used) when rec has columns (a run recording its values); rec, grown when full."""
    if rec.shape[1] == 0:
        return rec
    top = counts[2]
    m = ids.shape[0]
    if top + m > rec.shape[0]:
        more = np.zeros((2 * (top + m), 3))
        more[:top] = rec[:top]
        rec = more
    for r in range(m):
        rec[top + r, 0] = ids[r]
        rec[top + r, 1] = sites[r]
        rec[top + r, 2] = values[r]
    counts[2] = top + m
    return rec


@jit
def replay_weights(
    site_kind: np.ndarray,
    site: np.ndarray,
    args: np.ndarray,
    n_args: np.ndarray,
    values: np.ndarray,
    log_w: np.ndarray,
    log_prior: np.ndarray,
) -> None:
    """Replayed values (one particle, row r: its site, prior arguments args[r, :n_args[r]]
    and value) weighed as run._Run weighs a ReplayProposal's: log q = log p = the prior's
    log density (kernels._prior_lp, prior_logpdf's arithmetic), added row by row
    (add_weights)."""
    n = site.shape[0]
    lp = np.empty(n)
    for r in range(n):
        lp[r] = _prior_lp(site_kind[site[r]], args[r], n_args[r], values[r])
    add_weights(log_w, log_prior, np.zeros(n, dtype=np.int64), lp, lp)


@jit
def _grown(a: np.ndarray) -> np.ndarray:
    """A 3-d array with its second axis twice as long (zeros past the old end)."""
    out = np.zeros((a.shape[0], 2 * a.shape[1], a.shape[2]))
    out[:, : a.shape[1]] = a
    return out


@jit
def advance_at(
    addr: int,
    ids: np.ndarray,
    codes: np.ndarray,
    stack: np.ndarray,
    sp: np.ndarray,
    turtle: np.ndarray,
    tstack: np.ndarray,
    tsp: np.ndarray,
    vals: np.ndarray,
    nv: np.ndarray,
    need: np.ndarray,
    prim: np.ndarray,
    prim_par: np.ndarray,
    n_prims: np.ndarray,
    work: np.ndarray,
    resume: np.ndarray,
    dlen: int,
    angle: float,
    max_modules: int,
    max_work: int,
    max_prims: int,
    max_succ: int,
    rsite: np.ndarray,
    rval: np.ndarray,
    rep: np.ndarray,
    log: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The grammar's `advance` (geometry/compiled.py, at machine address addr) over
    particles ids, outcomes into codes; particles it stopped by GROW advanced again once
    their stack and turtle stack have room (grown: returned, with the other)."""
    n_grow: int = call_native(
        addr,
        (ids, stack, sp, turtle, tstack, tsp, vals, nv, need, prim, prim_par, n_prims, work,
         resume, codes, dlen, angle, max_modules, max_work, max_prims, rsite, rval, rep, log),
    )  # fmt: skip
    while n_grow > 0:
        where = np.flatnonzero(codes == GROW)
        todo = ids[where]
        top_sp = 0
        top_tsp = 0
        for i in todo:
            top_sp = max(top_sp, sp[i])
            top_tsp = max(top_tsp, tsp[i])
        if top_sp - 1 + max_succ > stack.shape[1]:
            stack = _grown(stack)
        if top_tsp >= tstack.shape[1]:
            tstack = _grown(tstack)
        part = np.zeros(todo.shape[0], dtype=np.int64)
        n_grow = call_native(
            addr,
            (todo, stack, sp, turtle, tstack, tsp, vals, nv, need, prim, prim_par, n_prims,
             work, resume, part, dlen, angle, max_modules, max_work, max_prims, rsite, rval,
             rep, log),
        )  # fmt: skip
        for j in range(where.shape[0]):
            codes[where[j]] = part[j]
    return stack, tstack


@jit
def prior_derive(
    addr: int,
    rng_at: np.ndarray,
    live: np.ndarray,
    stack: np.ndarray,
    sp: np.ndarray,
    turtle: np.ndarray,
    tstack: np.ndarray,
    tsp: np.ndarray,
    vals: np.ndarray,
    nv: np.ndarray,
    need: np.ndarray,
    prim: np.ndarray,
    prim_par: np.ndarray,
    n_prims: np.ndarray,
    work: np.ndarray,
    resume: np.ndarray,
    dlen: int,
    angle: float,
    max_modules: int,
    max_work: int,
    max_prims: int,
    max_succ: int,
    rsite: np.ndarray,
    rval: np.ndarray,
    rep: np.ndarray,
    log: np.ndarray,
    wait_ids: np.ndarray,
    wait_n: np.ndarray,
    drawn: np.ndarray,
    empty: np.ndarray,
    counts: np.ndarray,
    status: np.ndarray,
    limit: np.ndarray,
    reach: np.ndarray,
    site_kind: np.ndarray,
    normals: np.ndarray,
    log_prior: np.ndarray,
    rec: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A step of unguided SMC's rounds (run._Run._derive for the prior proposal) in one
    call: the live particles not waiting advanced (advance_at), then round by round
    SiteOrder's next site (prior_pick), its draws from the run's generator (standard
    normals where normals[site], else uniforms: sitekinds' prior_draw's one call) and its
    values (prior_serve), and the served particles advanced. Returns stack, tstack, vals
    and rec (new arrays where they grew). rng_at: the generator's addresses
    (native_call.generator_addresses)."""
    rng = generator_at(rng_at)
    counts[:] = 0
    group = start_rounds(live, need, wait_ids, wait_n)
    site = -1
    while True:
        codes = np.zeros(group.shape[0], dtype=np.int64)
        stack, tstack = advance_at(
            addr, group, codes, stack, sp, turtle, tstack, tsp, vals, nv, need, prim,
            prim_par, n_prims, work, resume, dlen, angle, max_modules, max_work, max_prims,
            max_succ, rsite, rval, rep, log,
        )  # fmt: skip
        site, m = prior_pick(
            group, codes, site, need, n_prims, wait_ids, wait_n, drawn, empty, counts,
            status, limit, reach,
        )  # fmt: skip
        if site < 0:
            break
        d = rng.standard_normal(m) if normals[site] else rng.random(m)
        group, vals, rec = prior_serve(
            site, d, need, wait_ids, wait_n, counts, site_kind, log_prior, vals, nv, rec
        )
    return stack, tstack, vals, rec


@jit
def guided_derive(
    addr: int,
    rng_at: np.ndarray,
    live: np.ndarray,
    stack: np.ndarray,
    sp: np.ndarray,
    turtle: np.ndarray,
    tstack: np.ndarray,
    tsp: np.ndarray,
    vals: np.ndarray,
    nv: np.ndarray,
    need: np.ndarray,
    prim: np.ndarray,
    prim_par: np.ndarray,
    n_prims: np.ndarray,
    work: np.ndarray,
    resume: np.ndarray,
    dlen: int,
    angle: float,
    max_modules: int,
    max_work: int,
    max_prims: int,
    max_succ: int,
    rsite: np.ndarray,
    rval: np.ndarray,
    rep: np.ndarray,
    log: np.ndarray,
    wait_ids: np.ndarray,
    wait_n: np.ndarray,
    drawn: np.ndarray,
    empty: np.ndarray,
    counts: np.ndarray,
    status: np.ndarray,
    limit: np.ndarray,
    reach: np.ndarray,
    width_bad: np.ndarray,
    normals: np.ndarray,
    n_turtle: int,
    shape: np.ndarray,
    idx: np.ndarray,
    site: np.ndarray,
    rows_turtle: np.ndarray,
    depth: np.ndarray,
    extra: np.ndarray,
    n_extra: np.ndarray,
    args: np.ndarray,
    n_args: np.ndarray,
    x: np.ndarray,
    view: np.ndarray,
    size: np.ndarray,
    offs: np.ndarray,
    target: np.ndarray,
    canvas: np.ndarray,
    ctx: np.ndarray,
    ctx_geom: np.ndarray,
    cells: np.ndarray,
    cell_t: np.ndarray,
    table: np.ndarray,
    w: np.ndarray,
    cols: np.ndarray,
    kinds: np.ndarray,
    temps: np.ndarray,
    n_out: np.ndarray,
    params: np.ndarray,
    out: np.ndarray,
    log_w: np.ndarray,
    log_prior: np.ndarray,
    rec: np.ndarray,
) -> tuple[int, int, int, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A step of guided SMC's rounds (compiled_run.CompiledRun._derive_guided) in one
    call: the live particles not waiting advanced (advance_at), then round by round the
    outcomes, site order and packing (guided_round), the run's draws (uniforms, and
    standard normals when a site's guide draws them: as run._Run._serve_kernel draws; rng_at
    as prior_derive's), the guide's serving (serve_take) and, when rec has columns, the
    (particle, site, value) rows into rec (counts[2]); the served particles advanced; a
    particle's windows and context kept for its next row at the same turtle
    (feature_windows' memo: the canvas is the step's throughout). Stops at a round the
    guide refuses: status 1 (a site whose feature width it refuses: a = the site) or 2 (a
    row with bad prior arguments: a = the row, b = the round's row count), with that
    round's row sites. Returns (status, a, b, stack, tstack, vals, rec, row sites).
    Long because it takes the deriver's and serve_round's arguments one by one (numba types
    flat arguments fast, tuples slowly)."""
    rng = generator_at(rng_at)
    counts[:] = 0
    group = start_rounds(live, need, wait_ids, wait_n)
    served = np.full(group.shape[0], -1, dtype=np.int64)
    no_rows = np.zeros(0)
    memo = np.empty((log_w.shape[0], _memo_width(ctx)), dtype=np.float32)
    memo_key = np.full((log_w.shape[0], 3), np.nan)  # the step's canvas: nothing kept yet
    while True:
        codes = np.zeros(group.shape[0], dtype=np.int64)
        stack, tstack = advance_at(
            addr, group, codes, stack, sp, turtle, tstack, tsp, vals, nv, need, prim,
            prim_par, n_prims, work, resume, dlen, angle, max_modules, max_work, max_prims,
            max_succ, rsite, rval, rep, log,
        )  # fmt: skip
        flat, group, sites, sizes, served = guided_round(
            group, codes, served, need, n_prims, wait_ids, wait_n, drawn, empty, counts,
            status, limit, reach, stack, sp, turtle, n_turtle,
        )  # fmt: skip
        m: int = group.shape[0]
        if m == 0:
            break
        any_normal = False
        for s in sites:
            if width_bad[s]:
                return 1, s, 0, stack, tstack, vals, rec, served
            any_normal = any_normal or normals[s]
        u = rng.random(m)
        z = rng.standard_normal(m) if any_normal else no_rows
        n, bad, vals = serve_take(
            flat, n_turtle, shape, idx, site, rows_turtle, depth, extra, n_extra, args,
            n_args, x, view, size, offs, target, canvas, ctx, ctx_geom, cells, cell_t, table,
            w, cols, kinds, temps, n_out, params, u, z, out, log_w, log_prior, group, vals,
            nv, need, memo, memo_key,
        )  # fmt: skip
        if bad >= 0:
            return 2, bad, n, stack, tstack, vals, rec, served
        rec = _record(rec, counts, group[:n], served[:n], out[:n, 0])
    return 0, 0, 0, stack, tstack, vals, rec, served


# observe_step's likelihoods: the shape similarity, the circuit density
SHAPE, CIRCUIT = 0, 1


@jit
def observe_step(
    drawn: np.ndarray,
    empty: np.ndarray,
    prim: np.ndarray,
    prim_par: np.ndarray,
    sp: np.ndarray,
    n_prims: np.ndarray,
    cap: int,
    status: np.ndarray,
    limit: np.ndarray,
    head: np.ndarray,
    prev: np.ndarray,
    cols: np.ndarray,
    top: int,
    image: np.ndarray,
    padded: np.ndarray,
    view: np.ndarray,
    wp: np.ndarray,
    starts: np.ndarray,
    like: int,
    sim: np.ndarray,
    box: np.ndarray,
    ll: np.ndarray,
    pot: np.ndarray,
    edge_sum: np.ndarray,
    filled: np.ndarray,
    gain: np.ndarray,
    vp: np.ndarray,
    log_w: np.ndarray,
    log_lik: np.ndarray,
    blank: float,
    has_blank: bool,
    live: np.ndarray,
) -> tuple[float, int, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The rest of a compiled run's step after its rounds, in one call (run._Run.step and
    compiled_run.CompiledRun._observe): the primitives of particles `drawn` (ascending)
    into the pool and the ended or capped particles marked (step_prims), drawn into the
    canvas (kernels.draw), the likelihood's increments (SHAPE: kernels.shape_increment on
    sim, box, ll with the target's gain; CIRCUIT: circuit_increment on edge_sum, filled,
    box, ll, pot, the potential's increments; NaN -> -inf) and the blank image's value for
    `empty` (when has_blank) added to log_w and log_lik; then the largest weight (NaN if any
    is), the live ones with zero weight dead, the live ones into live. Returns (largest
    weight, live count, the step's kind codes (int8) and parameters, prev, cols)."""
    n = drawn.shape[0]
    codes, par, prev, cols = step_prims(
        drawn, prim, prim_par, sp, n_prims, cap, status, limit, head, prev, cols, top
    )
    if n:
        bbox, y0, x0, new, hit_k, hit_pix = draw(
            image, padded, drawn, codes, par, np.zeros((0, 2)), np.zeros(n + 1, dtype=np.int64),
            view, wp, starts,
        )  # fmt: skip
        if like == SHAPE:
            inc = shape_increment(sim, box, ll, drawn, hit_k, hit_pix, gain, bbox, vp)
        else:
            inc = circuit_increment(
                edge_sum, filled, box, ll, pot, image, drawn, y0, x0, new, bbox, vp
            )
        for k in range(n):
            i = drawn[k]
            d = inc[k] if inc[k] == inc[k] else -np.inf
            log_w[i] += d
            log_lik[i] += d
    if has_blank:
        for i in empty:
            log_w[i] += blank
            log_lik[i] += blank
    most, n_live = _live_after(log_w, status, live)
    return most, n_live, codes, par, prev, cols


@jit
def step_prims(
    drawn: np.ndarray,
    prim: np.ndarray,
    prim_par: np.ndarray,
    sp: np.ndarray,
    n_prims: np.ndarray,
    cap: int,
    status: np.ndarray,
    limit: np.ndarray,
    head: np.ndarray,
    prev: np.ndarray,
    cols: np.ndarray,
    top: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A compiled run's step primitives: the kind codes (int8) and parameters of particles
    drawn, linked as rows top, top + 1, ... of the primitive pool (prev, cols: grown when
    full); the particles that ended marked done, those at the primitive cap limited.
    Returns (codes, parameters, prev, cols)."""
    n = drawn.shape[0]
    codes = np.empty(n, dtype=np.int8)
    par = np.empty((n, prim_par.shape[1]))
    if top + n > prev.shape[0]:
        size = max(2 * prev.shape[0], top + n)
        more_prev = np.empty(size, dtype=np.int64)
        more_prev[:top] = prev[:top]
        more_cols = np.empty((size, cols.shape[1]))
        more_cols[:top] = cols[:top]
        prev, cols = more_prev, more_cols
    for k in range(n):
        i = drawn[k]
        codes[k] = prim[i]
        cols[top + k, 0] = prim[i]
        for c in range(prim_par.shape[1]):
            par[k, c] = prim_par[i, c]
            cols[top + k, 1 + c] = prim_par[i, c]
        if sp[i] == 0:
            status[i] = 1  # done
        elif n_prims[i] >= cap:
            status[i] = 2  # limit: max primitives
            limit[i] = 2
    link_rows(head, prev, top, drawn)
    return codes, par, prev, cols


@jit
def _live_after(log_w: np.ndarray, status: np.ndarray, live: np.ndarray) -> tuple[float, int]:
    """observe_step's end: the largest weight (NaN if one is) and, the live particles with
    zero weight marked dead, the live ones into live; (largest, live count)."""
    most = log_w[0]
    for x in log_w:
        if x != x or most != most:
            most = np.nan
        elif x > most:
            most = x
    n_live = 0
    for i in range(log_w.shape[0]):
        if status[i] == 0 and log_w[i] == -np.inf:
            status[i] = 3  # dead
        if status[i] == 0:
            live[n_live] = i
            n_live += 1
    return most, n_live


# these kernels inline kernels.py's functions and other modules' constants, which numba's
# disk cache does not check: drop it when those files change (kernel_cache.py)
drop_stale_cache(
    __name__,
    ("kernels.py", "native_call.py", "geometry/compiled.py", "geometry/derive.py"),
)
