"""`ngpmc serve`'s API through Starlette's test client: the page and its files, options,
/api/grow's event stream (target, frames that rebuild the growing vine, done), /api/shape,
the examples, and bad input: every refusal is JSON `{"error": ...}` with a fitting status,
one run per client, a busy server, the time limit."""

from __future__ import annotations

import base64
import io
import json
import math
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip(
    "starlette", reason='ngpmc serve needs the [web] extra: pip install -e ".[web]"'
)
with warnings.catch_warnings():  # Starlette 1.x prefers httpx2 and warns about httpx
    warnings.simplefilter("ignore")
    try:
        from starlette.testclient import TestClient
    except (ImportError, RuntimeError):
        pytest.skip(
            "Starlette's test client needs httpx (pip install httpx)", allow_module_level=True
        )

from ngpm_runtime import bundled
from ngpm_runtime.image.targets import load_target
from ngpm_runtime.inference.smc import SMCState, take_arrays
from PIL import Image, ImageDraw
from repo_paths import REPO

from ngpm_compiler.cli import main
from ngpm_compiler.web.app import bind, create_app, make_server
from ngpm_compiler.web.config import Limits, load_config
from ngpm_compiler.web.runs import Run, RunCheck, RunStopped
from ngpm_compiler.web.sse import FrameStream

BASE = "http://127.0.0.1"


def png_url(img: Image.Image, fmt: str = "PNG") -> str:
    buf = io.BytesIO()
    img.save(buf, format=fmt)
    mime = {"PNG": "png", "JPEG": "jpeg", "PPM": "x-portable-pixmap"}.get(fmt, fmt.lower())
    return f"data:image/{mime};base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def drawing(size: int = 320) -> Image.Image:
    """A thick Y, dark on white, as the page sends its canvas."""
    img = Image.new("RGB", (size, size), "white")
    d = ImageDraw.Draw(img)
    s = size / 320
    d.line(
        [(160 * s, 300 * s), (160 * s, 170 * s), (70 * s, 50 * s)],
        fill="black",
        width=int(24 * s),
        joint="curve",
    )
    d.line([(160 * s, 170 * s), (250 * s, 50 * s)], fill="black", width=int(24 * s))
    return img


@pytest.fixture(scope="module")
def config() -> Any:
    return load_config()


@pytest.fixture()
def client(config: Any) -> TestClient:
    return TestClient(create_app(config), base_url=BASE)


def events(resp: Any) -> list[tuple[str, dict[str, Any]]]:
    """The (event, data) pairs of a server-sent event stream."""
    out: list[tuple[str, dict[str, Any]]] = []
    event = None
    for line in resp.iter_lines():
        if line.startswith("event:"):
            event = line[6:].strip()
        elif line.startswith("data:"):
            out.append((event or "message", json.loads(line[5:])))
    return out


def grow(client: TestClient, **body: Any) -> list[tuple[str, dict[str, Any]]]:
    body.setdefault("image", png_url(drawing()))
    with client.stream("POST", "/api/grow", json=body) as resp:
        assert resp.status_code == 200, resp.read()
        assert resp.headers["content-type"].startswith("text/event-stream")
        return events(resp)


def rebuild(frames: list[dict[str, Any]]) -> list[list[Any]]:
    """The vine the page shows after the frames: `reset` replaces it, `append` extends it."""
    prims: list[list[Any]] = []
    for f in frames:
        prims = list(f["prims"]) if f["mode"] == "reset" else prims + f["prims"]
    return prims


def decode_data_url(url: str, mime: str) -> bytes:
    head, data = url.split(",", 1)
    assert head == f"data:{mime};base64"
    return base64.b64decode(data)


def assert_error(resp: Any, status: int, *words: str) -> None:
    assert resp.status_code == status, (resp.status_code, resp.text)
    assert resp.headers["content-type"].startswith("application/json")
    body = resp.json()
    assert set(body) == {"error"} and isinstance(body["error"], str), body
    assert "Traceback" not in body["error"]
    for w in words:
        assert w.lower() in body["error"].lower(), body["error"]


# --------------------------------------------------------------------------- the page


def test_page_and_its_files_are_served(client: TestClient) -> None:
    resp = client.get("/")
    assert resp.status_code == 200
    assert "text/html" in resp.headers["content-type"]
    assert 'id="ink"' in resp.text and 'id="grow"' in resp.text
    for path, kind in (("/static/app.js", "javascript"), ("/static/style.css", "text/css")):
        r = client.get(path)
        assert r.status_code == 200 and kind in r.headers["content-type"]


def test_options_list_the_bundled_vines_and_guide_and_the_limits(client: TestClient) -> None:
    opts = client.get("/api/options").json()
    vines = opts["grammars"][0]
    assert (vines["id"], vines["source"]) == ("vines", "bundled")
    assert [g["id"] for g in vines["guides"]] == ["bundled"]
    assert opts["examples"] == list(bundled.DEMO_TARGETS)
    assert opts["limits"]["max_particles"] == Limits().max_particles
    assert opts["limits"]["default_particles"] == 10


def test_unknown_paths_methods_and_hosts_are_refused(client: TestClient) -> None:
    assert_error(client.get("/api/nothing"), 404, "no such page")
    assert_error(client.get("/api/grow"), 405, "GET")
    resp = client.get("/", headers={"host": "evil.example"})
    assert resp.status_code == 400  # DNS rebinding: only 127.0.0.1 / localhost


# --------------------------------------------------------------------------- growing


def test_grow_streams_the_target_frames_and_the_result(client: TestClient) -> None:
    evs = grow(client, particles=8, seed=1, polarity="dark")
    kinds = [e for e, _ in evs]
    assert kinds[0] == "target" and kinds[-1] == "done"
    assert set(kinds[1:-1]) == {"frame"} and len(kinds) > 5
    target = evs[0][1]
    assert target["viewport"] == list(bundled.bundled_program().viewport)
    assert target["guide"] == "bundled vines guide" and target["particles"] == 8
    mask = Image.open(io.BytesIO(decode_data_url(target["mask"], "image/png")))
    assert mask.size == (50, 50)
    x, y, dx, dy = target["start"]
    assert 0.4 < x < 0.6 and y > 0.7 and dy < -0.9  # automatic: the Y's foot, heading up

    frames = [d for e, d in evs if e == "frame"]
    assert frames[0]["mode"] == "append"
    steps = [f["step"] for f in frames]
    assert steps == sorted(steps)
    vine = rebuild(frames)
    assert vine and all(p[0] in ("seg", "leaf", "disk", "poly") for p in vine)

    done = evs[-1][1]
    assert done["guided"] is True and done["particles"] == 8
    assert 0.2 < done["similarity"] <= 1.0 and done["seconds"] > 0
    assert done["primitives"] and done["steps"] >= len(frames)
    png = Image.open(io.BytesIO(decode_data_url(done["png"], "image/png")))
    assert png.size == (512, 512)
    svg = decode_data_url(done["svg"], "image/svg+xml").decode()
    assert svg.startswith("<svg") and svg.count("<line") > 0


def test_grow_is_reproducible_and_honors_guide_start_and_particles(client: TestClient) -> None:
    a = grow(client, seed=3, particles=5, polarity="dark")[-1][1]
    b = grow(client, seed=3, particles=5, polarity="dark")[-1][1]
    assert a["primitives"] == b["primitives"] and a["similarity"] == b["similarity"]

    start = {"x": 0.5, "y": 0.9, "dx": 0.0, "dy": -2.0}
    evs = grow(client, guide=None, particles=3, start=start, polarity="dark")
    assert evs[0][1]["guide"] is None and evs[0][1]["start"] == [0.5, 0.9, 0.0, -1.0]
    assert evs[-1][0] == "done" and evs[-1][1]["guided"] is False

    evs = grow(client, guide="bundled", particles=1, start=[0.5, 0.9, 0, -1])
    assert evs[-1][0] == "done" and evs[-1][1]["particles"] == 1


def test_a_picture_with_a_light_shape_on_dark_and_other_formats_grow(client: TestClient) -> None:
    inverted = Image.eval(drawing(200).convert("L"), lambda v: 255 - v)
    for fmt in ("JPEG", "GIF", "BMP", "WEBP"):
        evs = grow(client, image=png_url(inverted.convert("RGB"), fmt), particles=2)
        assert evs[-1][0] == "done", (fmt, evs[-1])


def test_frame_stream_follows_the_best_particle_through_resampling() -> None:
    sent: list[dict[str, Any]] = []
    stream = FrameStream(lambda e, d: sent.append(d))
    state = SMCState(3, np.zeros(3))

    def step(drawn: list[int], prims: list[tuple], ll: list[float]) -> None:
        state.drawn, state.prims = drawn, prims
        state.log_likelihood[:] = ll
        stream.step_done(state)

    seg = [("seg", float(i), 0.0, float(i), 1.0, 0.5) for i in range(6)]
    step([0, 1, 2], seg[:3], [0.0, 1.0, 0.0])  # best: particle 1
    step([0, 1], seg[3:5], [2.0, 1.0, 0.0])  # best: particle 0, another lineage
    anc = np.array([0, 0, 2])  # resampling, as smc() does it to every registered array
    take_arrays(state.arrays, anc)
    step([1], seg[5:], [2.0, 3.0, 0.0])  # best: particle 1, a copy of 0 that grew
    step([2], [seg[0]], [2.0, 3.0, 0.0])  # the best did not change: no frame
    step([], [], [2.0, 3.0, 0.0])  # nothing drew: no frame, no step counted
    assert [(f["mode"], f["prims"]) for f in sent] == [
        ("append", [list(seg[1])]),
        ("reset", [list(seg[0]), list(seg[3])]),
        ("append", [list(seg[5])]),
    ]
    assert rebuild(sent) == [list(seg[0]), list(seg[3]), list(seg[5])]
    assert stream.steps == 4 and [f["step"] for f in sent] == [1, 2, 3]


def test_run_check_stops_a_cancelled_run_after_a_step_that_drew() -> None:
    run = Run("me", 60.0)
    check = RunCheck(run)
    state = SMCState(2, np.zeros(2))
    run.cancel.set()
    check.step_done(state)  # nothing drew: the run goes on
    state.drawn = [0]
    with pytest.raises(RunStopped, match="stopped"):
        check.step_done(state)


def test_a_run_stops_when_cancelled_or_out_of_time() -> None:
    run = Run("me", 60.0)
    run.check()
    run.cancel.set()
    with pytest.raises(RunStopped, match="stopped"):
        run.check()
    with pytest.raises(RunStopped, match="time limit"):
        Run("me", 0.0).check()


# --------------------------------------------------------------------------- bad input


def big_png(w: int, h: int) -> str:
    return png_url(Image.new("1", (w, h), 1))


BAD_GROW = [
    ({"particles": 0}, 400, "'particles' must be from 1 to 500"),
    ({"particles": 501}, 400, "from 1 to 500"),
    ({"particles": "ten"}, 400, "whole number"),
    ({"particles": True}, 400, "whole number"),
    ({"particles": 2.5}, 400, "whole number"),
    ({"seed": -1}, 400, "'seed'"),
    ({"grammar": "oak"}, 400, "unknown grammar 'oak'"),
    ({"grammar": 3}, 400, "unknown grammar"),
    ({"guide": "mine"}, 400, "unknown guide 'mine'"),
    ({"start": {"x": 1.5, "y": 0, "dx": 0, "dy": -1}}, 400, "[0, 1]"),
    ({"start": {"x": 0.5, "y": 0.5, "dx": 0, "dy": 0}}, 400, "must not be zero"),
    ({"start": [0.5, 0.5, 1]}, 400, "four numbers"),
    ({"start": {"x": 0.5, "y": 0.5, "dx": 0, "dy": "up"}}, 400, "four numbers"),
    ({"polarity": "purple"}, 400, "'polarity'"),
    ({"colour": "green"}, 400, "unknown field(s): colour"),
    ({"image": None}, 400, "data url"),
    ({"image": "data:image/png,abc"}, 400, "base64 data url"),
    ({"image": "data:image/png;base64,&&&"}, 400, "not valid base64"),
    (
        {"image": "data:image/png;base64," + base64.b64encode(b"hello").decode()},
        415,
        "not an image",
    ),
    (
        {
            "image": "data:image/png;base64,"
            + base64.b64encode(b"\x89PNG\r\n\x1a\n" + b"\0" * 60).decode()
        },
        415,
        "not an image",
    ),
    ({"image": png_url(Image.new("RGB", (40, 40)), "PPM")}, 415, "PPM images are not accepted"),
    ({"image": big_png(4097, 16)}, 413, "4097 x 16 px"),
    ({"image": png_url(Image.new("RGB", (300, 300), "white"))}, 422, "holds no shape"),
    ({"image": png_url(Image.new("RGB", (4, 4), "white"))}, 422, "tiny"),
    ({"image": png_url(Image.new("RGB", (300, 300), "black"))}, 422, "holds no shape"),
]


@pytest.mark.parametrize(
    "body, status, words", BAD_GROW, ids=[f"{i}-{s}" for i, (_, s, _) in enumerate(BAD_GROW)]
)
def test_bad_grow_requests_get_a_clear_json_error(
    client: TestClient, body: dict[str, Any], status: int, words: str
) -> None:
    full = {"image": png_url(drawing(100)), **body}
    assert_error(client.post("/api/grow", json=full), status, words)


def test_a_truncated_image_and_a_shape_too_small_are_422_or_400(client: TestClient) -> None:
    buf = io.BytesIO()
    drawing(200).save(buf, format="PNG")
    cut = "data:image/png;base64," + base64.b64encode(buf.getvalue()[:400]).decode()
    assert_error(client.post("/api/grow", json={"image": cut}), 400, "cannot decode")
    dot = Image.new("RGB", (500, 500), "white")
    ImageDraw.Draw(dot).rectangle((10, 10, 14, 14), fill="black")
    assert_error(
        client.post("/api/grow", json={"image": png_url(dot), "polarity": "dark"}), 422, "no shape"
    )


def test_bodies_that_are_not_json_objects_are_refused(client: TestClient) -> None:
    assert_error(
        client.post(
            "/api/grow",
            content=b"image=1",
            headers={"content-type": "application/x-www-form-urlencoded"},
        ),
        415,
        "json",
    )
    assert_error(
        client.post(
            "/api/grow", content=b"{not json", headers={"content-type": "application/json"}
        ),
        400,
        "not valid json",
    )
    assert_error(client.post("/api/grow", json=[1, 2]), 400, "json object")
    assert_error(client.post("/api/grow", json={}), 400, "'image' is missing")


def test_deep_or_crowded_json_is_a_400_not_a_crash(client: TestClient) -> None:
    """Finding 7: deeply nested JSON made the parser raise RecursionError (a 500). Depth
    and the count of values are checked before parsing; strings may hold anything."""
    json_type = {"content-type": "application/json"}
    deep = b'{"image": ' + b"[" * 100_000 + b"]" * 100_000 + b"}"
    nine = b'{"image": ' + b"[" * 8 + b"]" * 8 + b"}"
    for path in ("/api/grow", "/api/shape"):
        assert_error(
            client.post(path, content=deep, headers=json_type),
            400,
            "too many values (more than 256)",
        )
        assert_error(
            client.post(path, content=nine, headers=json_type),
            400,
            "nested too deeply (more than 8 levels",
        )
    crowded = json.dumps({"image": png_url(drawing(100)), "seed": [0] * 5000}).encode()
    assert_error(
        client.post("/api/grow", content=crowded, headers=json_type), 400, "too many values"
    )
    odd = {"image": png_url(drawing(100)), "grammar": '[[[[[[[[[[{{{{,,,,\\"'}
    assert_error(client.post("/api/grow", json=odd), 400, "unknown grammar")


def test_oversized_requests_and_images_are_413(config: Any) -> None:
    small = load_config(limits=Limits(max_body_bytes=2000, max_image_bytes=1000))
    client = TestClient(create_app(small), base_url=BASE)
    noisy = Image.fromarray(np.random.default_rng(0).integers(0, 255, (60, 60, 3), np.uint8))
    assert_error(client.post("/api/grow", json={"image": png_url(noisy)}), 413, "larger than")
    limited = load_config(limits=Limits(max_image_bytes=1000))
    client = TestClient(create_app(limited), base_url=BASE)
    assert_error(
        client.post("/api/grow", json={"image": png_url(noisy)}), 413, "image file is larger than"
    )


def peer(app: Any, address: str) -> TestClient:
    """A test client that connects from `address`."""
    return TestClient(app, base_url=BASE, client=(address, 50000))


def test_one_run_per_client_and_a_busy_server(config: Any) -> None:
    app = create_app(load_config(limits=Limits(max_runs=2)))
    body = {"image": png_url(drawing(100)), "particles": 1}
    mine = app.state.slots.acquire("127.0.0.2")  # a run of this client is going
    assert_error(
        peer(app, "127.0.0.2").post("/api/grow", json=body),
        409,
        "from your address (127.0.0.2) is still going",
    )
    other = app.state.slots.acquire("127.0.0.3")  # and a second client's: full
    resp = peer(app, "127.0.0.4").post("/api/grow", json=body)
    assert_error(resp, 503, "busy")
    assert resp.headers["retry-after"] == "2"
    app.state.slots.release(mine)
    app.state.slots.release(other)
    with peer(app, "127.0.0.2").stream("POST", "/api/grow", json=body) as resp:
        assert resp.status_code == 200
        assert events(resp)[-1][0] == "done"
    assert app.state.slots.active() == 0


def test_a_client_cannot_take_more_slots_by_naming_itself_anew(config: Any) -> None:
    """Finding 8: run slots belong to the client's address, not to a header or cookie it
    sends (rotating X-Client-Id used to take every slot)."""
    app = create_app(load_config(limits=Limits(max_runs=2)))
    mine = app.state.slots.acquire("127.0.0.2")
    client = peer(app, "127.0.0.2")
    body = {"image": png_url(drawing(100)), "particles": 1}
    for name in ("client-aaaaaaaa", "client-bbbbbbbb"):
        resp = client.post(
            "/api/grow", json=body, headers={"x-client-id": name, "cookie": f"ngpm_client={name}"}
        )
        assert_error(resp, 409, "still going")
    assert app.state.slots.active() == 1
    app.state.slots.release(mine)


def test_two_clients_grow_at_once_as_they_would_alone(config: Any) -> None:
    app = create_app(config)
    alone = [
        grow(TestClient(app, base_url=BASE), seed=s, particles=6)[-1][1]["primitives"]
        for s in (1, 2)
    ]
    results: dict[int, Any] = {}

    def one(seed: int) -> None:
        results[seed] = grow(peer(app, f"127.0.0.{seed + 1}"), seed=seed, particles=6)[-1]

    threads = [threading.Thread(target=one, args=(s,)) for s in (1, 2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert [results[s][0] for s in (1, 2)] == ["done", "done"]
    assert [results[s][1]["primitives"] for s in (1, 2)] == alone  # shared guide, no crosstalk


def test_a_run_over_its_time_limit_ends_with_an_error_event(config: Any) -> None:
    app = create_app(load_config(limits=Limits(timeout_s=1e-9)))
    client = TestClient(app, base_url=BASE)
    evs = grow(client, particles=4)
    assert evs[-1][0] == "error" and "time limit" in evs[-1][1]["error"]
    assert app.state.slots.active() == 0  # the slot is free again
    assert grow(client, particles=4)[-1][0] == "error"


# --------------------------------------------------------------------------- pictures in


def test_shape_finds_the_shape_of_an_uploaded_picture(client: TestClient) -> None:
    light_on_dark = Image.new("RGB", (400, 200), (20, 20, 40))
    ImageDraw.Draw(light_on_dark).ellipse((150, 50, 250, 150), fill=(250, 240, 200))
    out = client.post("/api/shape", json={"image": png_url(light_on_dark, "JPEG")}).json()
    mask = np.asarray(Image.open(io.BytesIO(decode_data_url(out["mask"], "image/png"))))
    assert mask.shape == (256, 256, 4) and out["size"] == [256, 256]
    opaque = mask[..., 3] > 0
    assert opaque[128, 128] and not opaque[5, 128] and not opaque[128, 5]
    assert 0.05 < opaque.mean() < 0.3  # the disk, padded to a square
    assert_error(
        client.post("/api/shape", json={"image": png_url(Image.new("L", (50, 50)))}),
        422,
        "no shape",
    )
    assert_error(client.post("/api/shape", json={"image": "x", "extra": 1}), 400, "extra")


def data_url(img: Image.Image, fmt: str, **save: Any) -> str:
    buf = io.BytesIO()
    img.save(buf, format=fmt, **save)
    return f"data:image/{fmt.lower()};base64," + base64.b64encode(buf.getvalue()).decode()


def test_pictures_are_read_as_ngpmc_grow_reads_them(client: TestClient, tmp_path: Path) -> None:
    """Findings 7 and 8: a LAB TIFF was a 500, and an animated GIF whose first frame is
    blank was refused (422) although `ngpmc grow` takes its first frame with a shape. Both
    now go through the runtime's one loader: the same mask as the command line's."""
    shape = drawing(160)
    blank = Image.new("RGB", shape.size, "white")
    gif = tmp_path / "anim.gif"
    blank.save(gif, save_all=True, append_images=[shape], duration=100, loop=0)
    lab = tmp_path / "lab.tif"
    shape.convert("LAB").save(lab)
    for path in (gif, lab):
        url = data_url(Image.open(path), "GIF" if path == gif else "TIFF", save_all=True)
        resp = client.post("/api/shape", json={"image": url})
        assert resp.status_code == 200, resp.text
        evs = grow(client, image=url, particles=2)
        assert evs[-1][0] == "done", evs[-1]
        png = Image.open(io.BytesIO(decode_data_url(evs[0][1]["mask"], "image/png")))
        assert np.array_equal(np.asarray(png)[..., 3] > 0, load_target(path).mask), path.name
    flat = [Image.new("RGB", shape.size, (250 - k,) * 3) for k in range(3)]
    url = data_url(flat[0], "GIF", save_all=True, append_images=flat[1:])
    assert_error(client.post("/api/shape", json={"image": url}), 422, "holds no shape")


def test_pictures_are_decoded_a_few_at_a_time(config: Any) -> None:
    """Finding 6: /api/shape was not bounded by --max-runs (twelve float TIFFs at once
    took 2.5 GB); every picture, /api/grow's too, now takes one of max_runs decode slots."""
    app = create_app(load_config(limits=Limits(max_runs=1)))
    client = TestClient(app, base_url=BASE)
    body = {"image": png_url(drawing(100))}
    assert app.state.decode_slots.acquire(blocking=False)  # a picture is being read
    for path in ("/api/shape", "/api/grow"):
        resp = client.post(path, json=body)
        assert_error(resp, 503, "busy reading other pictures")
        assert resp.headers["retry-after"] == "2"
    app.state.decode_slots.release()
    assert client.post("/api/shape", json=body).status_code == 200
    assert app.state.decode_slots.acquire(blocking=False)  # the slot was given back
    app.state.decode_slots.release()


def test_examples_are_the_demo_pictures_with_their_starts(client: TestClient) -> None:
    assert client.get("/api/examples").json()["examples"] == list(bundled.DEMO_TARGETS)
    heart = client.get("/api/examples/heart").json()
    assert heart["name"] == "heart" and len(heart["start"]) == 4
    Image.open(io.BytesIO(decode_data_url(heart["mask"], "image/png"))).verify()
    assert_error(client.get("/api/examples/tree"), 404, "no example 'tree'")


# --------------------------------------------------------------------------- configuration


def test_command_line_grammars_and_guides_are_offered() -> None:
    vines_lsys = str(REPO / "grammars" / "vines.lsys")
    cfg = load_config(vines_lsys)
    assert [g.id for g in cfg.grammars] == ["cli", "vines"]
    assert [c.id for c in cfg.grammars[0].guides] == ["bundled"]  # same grammar hash
    cfg = load_config(str(REPO / "grammars" / "chain.lsys"))
    assert cfg.grammars[0].guides == [] and "chain" in cfg.grammars[0].name
    cfg = load_config(guide=str(bundled.guide_path()))
    assert [c.id for c in cfg.grammars[0].guides] == ["cli", "bundled"]
    assert load_config(guide="none").grammars[0].guides == []
    client = TestClient(
        create_app(load_config(str(REPO / "grammars" / "chain.lsys"))), base_url=BASE
    )
    opts = client.get("/api/options").json()
    assert [g["id"] for g in opts["grammars"]] == ["cli", "vines"]
    evs = grow(client, grammar="cli", particles=3)
    assert evs[0][1]["guide"] is None and evs[-1][0] == "done"
    assert_error(
        client.post(
            "/api/grow", json={"image": png_url(drawing(100)), "grammar": "cli", "guide": "bundled"}
        ),
        400,
        "unknown guide",
    )


def test_serve_command_errors_are_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit, match="2"):  # argparse refuses it
        main(["serve", "--port", "70000"])
    assert "argument --port: must be from 0 to 65535" in capsys.readouterr().err
    assert main(["serve", "--grammar", "nope.lsys"]) == 1
    assert "nope.lsys: no such grammar file" in capsys.readouterr().err
    tree = str(REPO / "grammars" / "tree3d.lsys")
    assert main(["serve", "--grammar", tree, "--guide", "none"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "tree3d.lsys is a 3D grammar" in err
    assert "grows 2D grammars into pictures" in err
    assert f"`ngpmc sample {tree} -o tree.glb --png tree.png`" in err
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        assert main(["serve", "--port", str(port)]) == 1
    err = capsys.readouterr().err
    assert "cannot listen on 127.0.0.1" in err and "Traceback" not in err


@pytest.fixture()
def live() -> Iterator[tuple[int, Any]]:
    """A real server (uvicorn, in a thread, on 127.0.0.1) whose requests must arrive within
    2 s, serving at most 8 connections at once: its port and the uvicorn server."""
    pytest.importorskip("uvicorn", reason="ngpmc serve needs the [web] extra (uvicorn)")
    limits = Limits(request_timeout_s=2.0, max_connections=8)
    sock = bind(0)
    server = make_server(load_config(guide="none", limits=limits), sock)
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    try:
        for _ in range(600):
            if server.started:
                break
            time.sleep(0.05)
        assert server.started, "the server did not start in 30 s"
        yield sock.getsockname()[1], server
    finally:
        server.should_exit = True
        thread.join(30)
        sock.close()


def seconds_held(
    socks: list[socket.socket], trickles: list[bytes], limit: float = 8.0
) -> list[float]:
    """Send each socket the next byte of its trickle every 0.2 s until the server closes
    it: the seconds each stayed open (inf: still open after `limit`)."""
    t0 = time.monotonic()
    held = [math.inf] * len(socks)
    for s in socks:
        s.setblocking(False)
    step = 0
    while time.monotonic() - t0 < limit and math.inf in held:
        for i, s in enumerate(socks):
            if held[i] != math.inf:
                continue
            try:
                if s.recv(65536) == b"":
                    held[i] = time.monotonic() - t0
                    continue
            except BlockingIOError:
                pass
            except OSError:
                held[i] = time.monotonic() - t0
                continue
            try:
                s.send(trickles[i][step % len(trickles[i]) :][:1])
            except BlockingIOError:
                pass
            except OSError:
                held[i] = time.monotonic() - t0
        step += 1
        time.sleep(0.2)
    return held


def status_of(port: int, path: str) -> int:
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=10) as resp:
            return resp.status
    except urllib.error.HTTPError as err:
        return err.code


def test_slow_clients_are_cut_off_and_cannot_crowd_the_server(live: tuple[int, Any]) -> None:
    """Finding 8: clients that send their request slowly (a header byte now and then, or a
    body byte) were held forever. Now a request must arrive within request_timeout_s (2 s
    here); beyond max_connections (8) held connections, requests get 503 meanwhile."""
    port, server = live
    head = b"GET /api/options HTTP/1.1\r\nHost: 127.0.0.1\r\n"
    post = (
        b"POST /api/shape HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: "
        b"application/json\r\nContent-Length: 5000\r\n\r\n{"
    )
    # The server must see each connection (and each post's request) before the next comes:
    # a request whose headers are in counts the connections open when they arrive, so a
    # post that arrived after all 8 were open would get 503 (and its connection closed).
    state = server.server_state
    socks, trickles = [], []
    for k in range(8):
        s = socket.create_connection(("127.0.0.1", port), timeout=10)
        if k == 0:  # one full request first, then the next one slowly (keep-alive)
            s.sendall(head + b"\r\n")
            assert s.recv(65536).startswith(b"HTTP/1.1 200")
        else:
            s.sendall(post if k < 5 else head)
        socks.append(s)
        trickles.append(b" " if 0 < k < 5 else b"X-Slow: 1\r\n")
        posts = min(k, 4)
        t0 = time.monotonic()
        while (len(state.connections), len(state.tasks)) != (k + 1, posts):
            assert time.monotonic() - t0 < 10, (k, len(state.connections), len(state.tasks))
            time.sleep(0.005)
    try:
        assert status_of(port, "/api/options") == 503  # 8 connections held: full
        held = seconds_held(socks, trickles)
    finally:
        for s in socks:
            s.close()
    assert max(held) < 5.0, held  # 2 s, plus slack for a busy machine
    assert status_of(port, "/api/options") == 200


def test_serve_prints_the_url_answers_and_stops_on_ctrl_c() -> None:
    pytest.importorskip("uvicorn", reason="ngpmc serve needs the [web] extra (uvicorn)")
    exe = shutil.which("ngpmc")
    cmd = [exe] if exe else [sys.executable, "-m", "ngpm_compiler.cli"]
    proc = subprocess.Popen(
        [*cmd, "serve", "--port", "0"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        lines = [proc.stdout.readline(), proc.stdout.readline()]
        assert lines[0].startswith("ngpmc serve: vines (1 guide)"), lines
        url = re.search(r"open (http://127\.0\.0\.1:\d+/)", lines[1]).group(1)
        with urllib.request.urlopen(url + "api/options", timeout=30) as resp:
            assert json.load(resp)["grammars"][0]["id"] == "vines"
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err
    assert "stopped" in out and "Traceback" not in err
