// ngpmc serve: draw a shape, grow a vine into it (POST /api/grow answers server-sent events).
"use strict";

const $ = (id) => document.getElementById(id);
const INK = "#1f2a24";
const START_COLOR = "#e0671b";
// render.py's palette: branches from thin (green) to thick (brown), leaves, flowers, polygons
const BRANCH_THIN = [46, 92, 44], BRANCH_THICK = [112, 74, 40];
const LEAF = "rgb(74,160,64)", FLOWER = "rgb(236,138,178)", POLY = "rgb(96,172,84)";

const ink = $("ink"), vine = $("vine"), marks = $("marks"), stage = $("stage");
const inkCtx = ink.getContext("2d", { willReadFrequently: true });
const vineCtx = vine.getContext("2d");
const marksCtx = marks.getContext("2d");
const W = ink.width, H = ink.height;

const state = {
  tool: "brush",
  brush: 34,
  undo: [],
  empty: true,
  start: null,          // placed start {x, y, dx, dy} (normalized, y down) or null
  autoStart: null,      // the start the server chose, shown after a run
  options: null,
  guided: true,
  run: null,            // {controller} while a run streams
  viewport: null,
  prims: [],
  queue: [],
  final: null,
  animating: false,
};

// ---------------------------------------------------------------- drawing

function snapshot() {
  state.undo.push({ img: inkCtx.getImageData(0, 0, W, H), empty: state.empty, start: state.start });
  if (state.undo.length > 30) state.undo.shift();
  $("undo").disabled = false;
}

function undo() {
  const last = state.undo.pop();
  if (!last) return;
  inkCtx.putImageData(last.img, 0, 0);
  state.empty = last.empty;
  state.start = last.start;
  if (state.start) $("auto-start").checked = false;
  $("undo").disabled = state.undo.length === 0;
  changed();
}

function changed() {
  $("hint").hidden = !state.empty;
  clearVine();
  drawMarks();
  updateStartNote();
}

function clearVine() {
  state.prims = []; state.queue = []; state.final = null; state.autoStart = null;
  vineCtx.clearRect(0, 0, W, H);
  stage.classList.remove("grown");
}

function pos(ev) {
  const r = ink.getBoundingClientRect();
  return { x: (ev.clientX - r.left) * W / r.width, y: (ev.clientY - r.top) * H / r.height };
}

let stroke = null;
stage.addEventListener("pointerdown", (ev) => {
  if (ev.button !== 0 || state.run) return;
  ev.preventDefault();
  stage.setPointerCapture(ev.pointerId);
  const p = pos(ev);
  if (state.tool === "start") {
    snapshot();
    stroke = { start: p };
    setStart({ x: p.x / W, y: p.y / H, dx: 0, dy: -1 });
    return;
  }
  snapshot();
  if (stage.classList.contains("grown")) clearVine();
  stroke = { last: p };
  inkCtx.globalCompositeOperation = state.tool === "eraser" ? "destination-out" : "source-over";
  inkCtx.fillStyle = INK;
  inkCtx.beginPath();
  inkCtx.arc(p.x, p.y, state.brush / 2, 0, 2 * Math.PI);
  inkCtx.fill();
  if (state.tool === "brush") { state.empty = false; $("hint").hidden = true; }
});

stage.addEventListener("pointermove", (ev) => {
  if (!stroke) return;
  const events = ev.getCoalescedEvents ? ev.getCoalescedEvents() : [ev];
  for (const e of events.length ? events : [ev]) {
    const p = pos(e);
    if (stroke.start) {
      const dx = p.x - stroke.start.x, dy = p.y - stroke.start.y;
      if (Math.hypot(dx, dy) > 6) {
        setStart({ x: stroke.start.x / W, y: stroke.start.y / H, dx, dy });
      }
      continue;
    }
    inkCtx.strokeStyle = INK;
    inkCtx.lineWidth = state.brush;
    inkCtx.lineCap = "round";
    inkCtx.lineJoin = "round";
    inkCtx.beginPath();
    inkCtx.moveTo(stroke.last.x, stroke.last.y);
    inkCtx.lineTo(p.x, p.y);
    inkCtx.stroke();
    stroke.last = p;
  }
});

function endStroke() {
  if (!stroke) return;
  const wasErase = state.tool === "eraser";
  stroke = null;
  inkCtx.globalCompositeOperation = "source-over";
  if (wasErase) { state.empty = isInkEmpty(); $("hint").hidden = !state.empty; }
}
stage.addEventListener("pointerup", endStroke);
stage.addEventListener("pointercancel", endStroke);

function isInkEmpty() {
  const data = inkCtx.getImageData(0, 0, W, H).data;
  for (let i = 3; i < data.length; i += 16) if (data[i] > 40) return false;
  return true;
}

function setStart(s) {
  const n = Math.hypot(s.dx, s.dy) || 1;
  state.start = { x: clamp01(s.x), y: clamp01(s.y), dx: s.dx / n, dy: s.dy / n };
  $("auto-start").checked = false;
  state.autoStart = null;
  drawMarks();
  updateStartNote();
}

const clamp01 = (v) => Math.min(1, Math.max(0, v));

function drawArrow(ctx, s, dashed) {
  const x = s.x * W, y = s.y * H, len = 54;
  const ex = x + s.dx * len, ey = y + s.dy * len;
  ctx.save();
  ctx.lineWidth = 4;
  ctx.strokeStyle = START_COLOR;
  ctx.fillStyle = START_COLOR;
  ctx.lineCap = "round";
  ctx.shadowColor = "rgba(255,255,255,.9)";
  ctx.shadowBlur = 4;
  if (dashed) ctx.setLineDash([7, 6]);
  ctx.beginPath(); ctx.moveTo(x, y); ctx.lineTo(ex, ey); ctx.stroke();
  ctx.setLineDash([]);
  const a = Math.atan2(s.dy, s.dx);
  ctx.beginPath();
  ctx.moveTo(ex + 4 * Math.cos(a), ey + 4 * Math.sin(a));
  ctx.lineTo(ex - 14 * Math.cos(a - 0.5), ey - 14 * Math.sin(a - 0.5));
  ctx.lineTo(ex - 14 * Math.cos(a + 0.5), ey - 14 * Math.sin(a + 0.5));
  ctx.closePath(); ctx.fill();
  ctx.beginPath(); ctx.arc(x, y, 8, 0, 2 * Math.PI);
  ctx.fillStyle = "#fff"; ctx.fill(); ctx.stroke();
  ctx.restore();
}

function drawMarks() {
  marksCtx.clearRect(0, 0, W, H);
  if (state.start && !$("auto-start").checked) drawArrow(marksCtx, state.start, false);
  else if (state.autoStart) drawArrow(marksCtx, state.autoStart, true);
}

function updateStartNote() {
  const auto = $("auto-start").checked;
  const s = state.start;
  $("start-note").innerHTML = auto || !s
    ? "or pick <b>Start</b> and drag on the canvas"
    : `placed at (${s.x.toFixed(2)}, ${s.y.toFixed(2)}), heading ${headingText(s)}`;
}

function headingText(s) {
  const deg = Math.round(Math.atan2(-s.dy, s.dx) * 180 / Math.PI);
  return `${deg}°`;
}

// ---------------------------------------------------------------- tools and inputs

function setTool(tool) {
  state.tool = tool;
  stage.dataset.tool = tool;
  for (const b of document.querySelectorAll(".tool")) {
    const on = b.dataset.tool === tool;
    b.classList.toggle("active", on);
    b.setAttribute("aria-pressed", String(on));
  }
}
for (const b of document.querySelectorAll(".tool")) b.addEventListener("click", () => setTool(b.dataset.tool));
setTool("brush");

function setBrush(v) {
  state.brush = Number(v);
  const d = $("brush-dot"), px = Math.max(4, Math.round(state.brush * ink.getBoundingClientRect().width / W));
  d.style.width = d.style.height = `${Math.min(px, 30)}px`;
}
$("brush-size").addEventListener("input", (e) => setBrush(e.target.value));

$("undo").addEventListener("click", undo);
$("clear").addEventListener("click", () => {
  if (state.run) return;
  snapshot();
  inkCtx.clearRect(0, 0, W, H);
  state.empty = true;
  state.start = null;
  $("auto-start").checked = true;
  changed();
});
document.addEventListener("keydown", (e) => {
  if (e.target.closest && e.target.closest("input, select")) return;
  if ((e.ctrlKey || e.metaKey) && e.key.toLowerCase() === "z") { e.preventDefault(); undo(); }
  else if (e.key === "b") setTool("brush");
  else if (e.key === "e") setTool("eraser");
  else if (e.key === "s") setTool("start");
});

$("auto-start").addEventListener("change", () => { drawMarks(); updateStartNote(); });

function syncParticles(v, from) {
  const max = state.options ? state.options.limits.max_particles : 500;
  let n = Math.round(Number(v));
  if (!Number.isFinite(n)) return;
  n = Math.min(max, Math.max(1, n));
  if (from !== "number") $("particles").value = n;
  if (from !== "range") $("particles-range").value = Math.min(n, Number($("particles-range").max));
  $("particles-out").textContent = n;
}
$("particles-range").addEventListener("input", (e) => syncParticles(e.target.value, "range"));
$("particles").addEventListener("input", (e) => syncParticles(e.target.value, "number"));
$("particles").addEventListener("change", (e) => syncParticles(e.target.value));
$("dice").addEventListener("click", () => { $("seed").value = Math.floor(Math.random() * 100000); });

function setGuided(on) {
  const g = currentGrammar();
  if (on && g && g.guides.length === 0) on = false;
  state.guided = on;
  $("mode-guided").classList.toggle("active", on);
  $("mode-prior").classList.toggle("active", !on);
  $("mode-guided").setAttribute("aria-pressed", String(on));
  $("mode-prior").setAttribute("aria-pressed", String(!on));
  $("guide").hidden = !on || !g || g.guides.length < 2;
}
$("mode-guided").addEventListener("click", () => setGuided(true));
$("mode-prior").addEventListener("click", () => setGuided(false));

function currentGrammar() {
  if (!state.options) return null;
  return state.options.grammars.find((g) => g.id === $("grammar").value) || null;
}

function fillGuides() {
  const g = currentGrammar();
  const sel = $("guide");
  sel.innerHTML = "";
  for (const c of g ? g.guides : []) sel.add(new Option(c.name, c.id));
  $("mode-guided").disabled = !g || g.guides.length === 0;
  $("guide-note").textContent = g && g.guides.length === 0
    ? "This grammar has no trained guide: SMC proposes from the prior." : "";
  setGuided(g ? g.guides.length > 0 : false);
}
$("grammar").addEventListener("change", fillGuides);

// ---------------------------------------------------------------- pictures in

function paintMask(url, start) {
  return new Promise((resolve, reject) => {
    const img = new Image();
    img.onload = () => {
      snapshot();
      const off = document.createElement("canvas");
      off.width = W; off.height = H;
      const c = off.getContext("2d");
      c.imageSmoothingEnabled = true;
      c.drawImage(img, 0, 0, W, H);
      c.globalCompositeOperation = "source-in";
      c.fillStyle = INK;
      c.fillRect(0, 0, W, H);
      inkCtx.clearRect(0, 0, W, H);
      inkCtx.drawImage(off, 0, 0);
      state.empty = false;
      if (start) {
        setStart({ x: start[0], y: start[1], dx: start[2], dy: start[3] });
      } else {
        state.start = null;
        $("auto-start").checked = true;
      }
      changed();
      resolve();
    };
    img.onerror = () => reject(new Error("the shape could not be shown"));
    img.src = url;
  });
}

async function api(path, body) {
  const resp = await fetch(path, body === undefined ? {} : {
    method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body),
  });
  const data = await resp.json().catch(() => ({ error: `${resp.status} ${resp.statusText}` }));
  if (!resp.ok) throw new Error(data.error || `${resp.status} ${resp.statusText}`);
  return data;
}

$("upload").addEventListener("click", () => { if (!state.run) $("file").click(); });
$("file").addEventListener("change", async (e) => {
  const file = e.target.files[0];
  e.target.value = "";
  if (!file) return;
  hideError();
  const max = state.options ? state.options.limits.max_image_bytes : 8 << 20;
  if (file.size > max) { showError(`${file.name} is larger than ${(max / 2 ** 20).toFixed(0)} MiB`); return; }
  setStatus(`Reading ${file.name}…`);
  try {
    const url = await new Promise((resolve, reject) => {
      const r = new FileReader();
      r.onload = () => resolve(r.result);
      r.onerror = () => reject(new Error(`cannot read ${file.name}`));
      r.readAsDataURL(file);
    });
    const shape = await api("/api/shape", { image: url });
    await paintMask(shape.mask, null);
    setStatus(`${file.name}: its shape is on the canvas. Edit it, or Grow.`);
  } catch (err) {
    setStatus("Ready.");
    showError(`${file.name}: ${err.message}`);
  }
});

async function loadExample(name) {
  if (state.run) return;
  hideError();
  try {
    const ex = await api(`/api/examples/${encodeURIComponent(name)}`);
    await paintMask(ex.mask, ex.start);
    setStatus(`The ${name} example, with its start. Press Grow.`);
  } catch (err) {
    showError(err.message);
  }
}

// ---------------------------------------------------------------- growing

function inkPNG() {
  const off = document.createElement("canvas");
  off.width = W; off.height = H;
  const c = off.getContext("2d");
  c.fillStyle = "#fff";
  c.fillRect(0, 0, W, H);
  c.drawImage(ink, 0, 0);
  return off.toDataURL("image/png");
}

function setStatus(text) { $("status").textContent = text; }
function showError(text) { const e = $("error"); e.textContent = text; e.hidden = false; }
function hideError() { $("error").hidden = true; }

function setRunning(on) {
  const b = $("grow");
  b.classList.toggle("stop", on);
  $("grow-label").textContent = on ? "Stop" : "Grow";
  for (const id of ["undo", "clear", "upload", "grammar", "particles", "particles-range", "seed"]) {
    if (id === "undo") $(id).disabled = on || state.undo.length === 0;
    else $(id).disabled = on;
  }
}

async function grow() {
  if (state.run) { state.run.controller.abort(); return; }
  hideError();
  if (state.empty) { showError("Draw a shape first (or upload a picture, or pick an example)."); return; }
  const g = currentGrammar();
  const body = {
    image: inkPNG(),
    grammar: g ? g.id : undefined,
    guide: state.guided && g && g.guides.length ? $("guide").value || g.guides[0].id : null,
    particles: Number($("particles").value),
    seed: Number($("seed").value) || 0,
    start: $("auto-start").checked || !state.start ? null : state.start,
    polarity: "dark",
  };
  clearVine();
  $("result").dataset.state = "running";
  resetMetrics();
  const controller = new AbortController();
  state.run = { controller, t0: performance.now() };
  setRunning(true);
  setStatus("Starting…");
  let finished = false;
  try {
    let resp;
    for (let attempt = 0; ; attempt++) {
      resp = await fetch("/api/grow", {
        method: "POST", headers: { "Content-Type": "application/json" },
        body: JSON.stringify(body), signal: controller.signal,
      });
      // 409: the run just stopped is still winding down on the server; ask again shortly
      if (resp.status !== 409 || attempt >= 6) break;
      await new Promise((r) => setTimeout(r, 250));
    }
    if (!resp.ok) {
      const data = await resp.json().catch(() => ({ error: `${resp.status} ${resp.statusText}` }));
      throw new Error(data.error || resp.statusText);
    }
    const reader = resp.body.getReader();
    const decoder = new TextDecoder();
    let buf = "";
    for (;;) {
      const { value, done } = await reader.read();
      if (done) break;
      buf += decoder.decode(value, { stream: true });
      let cut;
      while ((cut = buf.indexOf("\n\n")) >= 0) {
        const block = buf.slice(0, cut);
        buf = buf.slice(cut + 2);
        let event = "message", data = "";
        for (const line of block.split("\n")) {
          if (line.startsWith("event:")) event = line.slice(6).trim();
          else if (line.startsWith("data:")) data += line.slice(5).trim();
        }
        if (onEvent(event, data ? JSON.parse(data) : {})) finished = true;
      }
    }
    if (!finished) throw new Error("the connection closed before the run finished");
  } catch (err) {
    if (err.name === "AbortError") setStatus("Stopped.");
    else { setStatus("Ready."); showError(err.message); }
    $("result").dataset.state = "idle";
  } finally {
    state.run = null;
    setRunning(false);
  }
}
$("grow").addEventListener("click", grow);

function onEvent(event, data) {
  if (event === "target") {
    state.viewport = data.viewport;
    $("model-view").src = data.mask;
    const [x, y, dx, dy] = data.start;
    if ($("auto-start").checked || !state.start) state.autoStart = { x, y, dx, dy };
    drawMarks();
    stage.classList.add("grown");
    setStatus(`Growing with ${data.particles} particle${data.particles === 1 ? "" : "s"}` +
              `${data.guide ? ", guided" : ", unguided"}…`);
    return false;
  }
  if (event === "frame") {
    state.queue.push(data);
    animate();
    return false;
  }
  if (event === "done") {
    state.final = data;
    animate();
    return true;
  }
  if (event === "error") {
    showError(data.error || "the run failed");
    setStatus("Ready.");
    $("result").dataset.state = "idle";
    return true;
  }
  return false;
}

// Frames are played back smoothly: a few per animation frame, more when many are waiting,
// so a run of a quarter of a second still shows the vine growing.
function animate() {
  if (state.animating) return;
  state.animating = true;
  const tick = () => {
    const q = state.queue;
    if (q.length) {
      const k = Math.max(1, Math.floor(q.length / 14));
      let last = null;
      for (let i = 0; i < k && q.length; i++) {
        last = q.shift();
        if (last.mode === "reset") state.prims = last.prims.slice();
        else for (const p of last.prims) state.prims.push(p);
      }
      drawVine(state.prims);
      if (state.run) {
        const secs = ((performance.now() - state.run.t0) / 1000).toFixed(1);
        setStatus(`Growing… step ${last.step}, ${state.prims.length} primitives, ${secs} s`);
      }
      requestAnimationFrame(tick);
      return;
    }
    if (state.final) {
      const f = state.final;
      state.final = null;
      state.prims = f.primitives;
      drawVine(state.prims);
      showResult(f);
    }
    state.animating = false;
  };
  requestAnimationFrame(tick);
}

function toCanvas(x, y) {
  const [xmin, xmax, ymin, ymax] = state.viewport;
  return [(x - xmin) / (xmax - xmin) * W, (ymax - y) / (ymax - ymin) * H];
}

function drawVine(prims) {
  vineCtx.clearRect(0, 0, W, H);
  if (!state.viewport) return;
  const [xmin, xmax] = state.viewport;
  const k = W / (xmax - xmin);
  let wmax = 0;
  for (const p of prims) if (p[0] === "seg") wmax = Math.max(wmax, Math.abs(p[5]));
  vineCtx.lineCap = "round";
  for (const p of prims) {
    if (p[0] === "seg") {
      const t = wmax > 0 ? Math.min(1, Math.abs(p[5]) / wmax) : 1;
      const c = BRANCH_THIN.map((a, i) => Math.round(a + (BRANCH_THICK[i] - a) * t));
      const [x0, y0] = toCanvas(p[1], p[2]), [x1, y1] = toCanvas(p[3], p[4]);
      vineCtx.strokeStyle = `rgb(${c})`;
      vineCtx.lineWidth = Math.max(1, Math.abs(p[5]) * k);
      vineCtx.beginPath(); vineCtx.moveTo(x0, y0); vineCtx.lineTo(x1, y1); vineCtx.stroke();
    } else if (p[0] === "leaf") {
      const [, x, y, hd, len, wid] = p;
      const r = hd * Math.PI / 180;
      const [cx, cy] = toCanvas(x + len / 2 * Math.cos(r), y + len / 2 * Math.sin(r));
      vineCtx.fillStyle = LEAF;
      vineCtx.beginPath();
      vineCtx.ellipse(cx, cy, Math.abs(len) / 2 * k, Math.abs(wid) / 2 * k, -r, 0, 2 * Math.PI);
      vineCtx.fill();
    } else if (p[0] === "disk") {
      const [cx, cy] = toCanvas(p[1], p[2]);
      vineCtx.fillStyle = FLOWER;
      vineCtx.beginPath(); vineCtx.arc(cx, cy, Math.abs(p[3]) * k, 0, 2 * Math.PI); vineCtx.fill();
    } else if (p[0] === "poly" && p[1].length) {
      vineCtx.fillStyle = POLY;
      vineCtx.beginPath();
      p[1].forEach(([x, y], i) => { const [u, v] = toCanvas(x, y); if (i) vineCtx.lineTo(u, v); else vineCtx.moveTo(u, v); });
      vineCtx.closePath(); vineCtx.fill("evenodd");
    }
  }
}

function resetMetrics() {
  $("similarity").textContent = "–";
  $("seconds").textContent = "–";
  $("detail").textContent = "";
  $("similarity-bar").style.width = "0";
  for (const id of ["dl-png", "dl-svg"]) {
    const a = $(id);
    a.classList.add("disabled"); a.removeAttribute("href"); a.setAttribute("aria-disabled", "true");
  }
}

function showResult(f) {
  $("similarity").textContent = f.similarity.toFixed(2);
  $("similarity-bar").style.width = `${Math.max(0, Math.min(1, f.similarity)) * 100}%`;
  $("seconds").textContent = f.seconds.toFixed(2);
  $("detail").textContent = `${f.primitives.length} primitives · ${f.steps} steps`;
  for (const [id, url] of [["dl-png", f.png], ["dl-svg", f.svg]]) {
    const a = $(id);
    a.href = url; a.classList.remove("disabled"); a.removeAttribute("aria-disabled");
  }
  $("result").dataset.state = "done";
  setStatus(`Done: ${f.particles} particle${f.particles === 1 ? "" : "s"}, ` +
            `${f.guided ? "guided" : "unguided"}. Draw more, or Grow again with another seed.`);
}

// ---------------------------------------------------------------- start up

async function init() {
  setBrush($("brush-size").value);
  try {
    const opts = await api("/api/options");
    state.options = opts;
    const sel = $("grammar");
    for (const g of opts.grammars) {
      sel.add(new Option(g.source === "bundled" ? `${g.name} (bundled)` : g.name, g.id));
    }
    fillGuides();
    const lim = opts.limits;
    $("particles").max = lim.max_particles;
    $("particles-range").max = Math.min(100, lim.max_particles);
    syncParticles(lim.default_particles);
    const chips = $("examples");
    for (const name of opts.examples) {
      const b = document.createElement("button");
      b.type = "button";
      b.textContent = name;
      b.dataset.example = name;
      b.addEventListener("click", () => loadExample(name));
      chips.appendChild(b);
    }
    document.body.dataset.ready = "1";
  } catch (err) {
    showError(`Cannot reach the server: ${err.message}`);
  }
}
window.addEventListener("resize", () => setBrush(state.brush));
init();
