"""The checks of what a client sends: the JSON body (bounded in size, depth and count of
values), the picture (through the runtime's one loader, as `ngpmc grow` reads it), the start
and the options of a run. Bad input raises `ApiError`, answered as JSON with its status."""

from __future__ import annotations

import base64
import binascii
import io
import json
import math
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from ngpm_runtime.errors import TargetError
from PIL import Image
from starlette.requests import ClientDisconnect, Request

from ngpm_compiler.web.config import GrammarChoice, GuideChoice, Limits, WebConfig

if TYPE_CHECKING:
    from ngpm_runtime.image.targets import Target

DATA_URL_RE = re.compile(r"^data:([\w.+/-]*)((?:;[\w.+-]+=[\w.+-]+)*)(;base64)?,", re.ASCII)
NOT_BRACKETS = bytes(c for c in range(256) if c not in b"[]{}")  # bytes.translate deletes
MAX_JSON_DEPTH = 8  # nested [ ] and { } in a request (the API needs 2)
MAX_JSON_VALUES = 256  # values and containers in a request (the API needs about 12)
POLARITIES = ("auto", "dark", "light", "alpha")
GROW_KEYS = ("image", "grammar", "guide", "particles", "seed", "start", "polarity")


class ApiError(Exception):
    """An error answered as JSON `{"error": message}` with `status`."""

    def __init__(self, status: int, message: str, headers: dict[str, str] | None = None):
        super().__init__(message)
        self.status = status
        self.message = message
        self.headers = headers


async def read_json(request: Request, limit: int) -> dict[str, Any]:
    """The request's JSON object, read with a cap on its size, depth and count of values."""
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if ctype != "application/json":
        raise ApiError(415, "send the request as JSON (Content-Type: application/json)")
    too_big = f"the request is larger than {_mib(limit)}"
    length = request.headers.get("content-length")
    if length is not None and length.isdigit() and int(length) > limit:
        raise ApiError(413, too_big)
    body = bytearray()
    try:
        async for chunk in request.stream():
            body += chunk
            if len(body) > limit:
                raise ApiError(413, too_big)
    except ClientDisconnect:  # gone, or cut off by the request deadline
        raise ApiError(400, "the request body did not arrive (in time)") from None
    check_json_shape(bytes(body))
    try:
        data = json.loads(bytes(body))
    except (ValueError, UnicodeDecodeError, RecursionError):
        raise ApiError(400, "the request body is not valid JSON") from None
    if not isinstance(data, dict):
        raise ApiError(400, "the request body must be a JSON object")
    return data


def check_json_shape(body: bytes) -> None:
    """Refuse JSON with more than MAX_JSON_VALUES values or nested deeper than
    MAX_JSON_DEPTH, before parsing it: deep nesting overflows the parser's stack, and many
    small values take far more memory than their bytes. A few passes at C speed: escapes
    dropped, strings cut out, then the brackets counted (at most 2 * MAX_JSON_VALUES + 1)."""
    plain = body.replace(b"\\\\", b"").replace(b'\\"', b"")  # now every quote is a delimiter
    too_many = ApiError(
        400, f"the request body holds too many values (more than {MAX_JSON_VALUES})"
    )
    if plain.count(b'"') > 2 * MAX_JSON_VALUES:
        raise too_many
    outside = b"".join(plain.split(b'"')[::2])  # the text outside strings
    if sum(outside.count(c) for c in (b"[", b"{", b",")) > MAX_JSON_VALUES:
        raise too_many
    depth = 0
    for byte in outside.translate(None, NOT_BRACKETS):
        depth += 1 if byte in b"[{" else -1
        if depth > MAX_JSON_DEPTH:
            raise ApiError(
                400,
                f"the request body is nested too deeply (more than "
                f"{MAX_JSON_DEPTH} levels of [ ] and {{ }})",
            )
        if depth < 0:  # unbalanced: the parser will say it is not JSON
            return


def _mib(n: int) -> str:
    return f"{n / 2**20:g} MiB"


def decode_image(value: Any, limits: Limits) -> Image.Image:
    """A PIL image from a data URL (or bare base64), through the runtime's one loader:
    format and size checked from the header before any pixel is decoded."""
    from ngpm_runtime.image.targets import (
        ImageDecodeError,
        ImageFormatError,
        ImageSizeError,
        read_image,
    )

    if not isinstance(value, str) or not value:
        raise ApiError(400, "'image' must be an image as a data URL (data:image/png;base64,...)")
    m = DATA_URL_RE.match(value)
    if value.startswith("data:"):
        if m is None or not m.group(3):
            raise ApiError(400, "'image' must be a base64 data URL (data:image/png;base64,...)")
        value = value[m.end() :]
    if len(value) * 3 // 4 > limits.max_image_bytes + 3:
        raise ApiError(413, f"the image file is larger than {_mib(limits.max_image_bytes)}")
    try:
        raw = base64.b64decode(value, validate=True)
    except (binascii.Error, ValueError):
        raise ApiError(400, "'image' is not valid base64") from None
    try:
        return read_image(
            io.BytesIO(raw), "the picture", max_side=limits.max_side, max_pixels=limits.max_side**2
        )
    except ImageFormatError as err:
        raise ApiError(415, str(err)) from None
    except ImageSizeError as err:
        raise ApiError(413, str(err)) from None
    except ImageDecodeError as err:
        raise ApiError(400, str(err)) from None
    except TargetError as err:  # an animation without a frame that holds a shape
        raise ApiError(422, target_message(err)) from None


def _int(body: dict[str, Any], key: str, default: int, lo: int, hi: int) -> int:
    value = body.get(key, default)
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int):
        raise ApiError(400, f"'{key}' must be a whole number from {lo} to {hi}")
    if not lo <= value <= hi:
        raise ApiError(400, f"'{key}' must be from {lo} to {hi}, got {value}")
    return value


def parse_start(value: Any) -> tuple[float, float, float, float] | None:
    """None (automatic) or (x, y, dx, dy): a point in [0, 1] from the top-left corner of the
    picture and a direction in image axes (y down)."""
    if value is None or value == "auto":
        return None
    if isinstance(value, dict):
        unknown = set(value) - {"x", "y", "dx", "dy"}
        if unknown or len(value) != 4:
            raise ApiError(400, "'start' must be null or {x, y, dx, dy}")
        value = [value["x"], value["y"], value["dx"], value["dy"]]
    if (
        not isinstance(value, list | tuple)
        or len(value) != 4
        or any(isinstance(v, bool) or not isinstance(v, int | float) for v in value)
    ):
        raise ApiError(400, "'start' must be null or {x, y, dx, dy} (four numbers)")
    x, y, dx, dy = (float(v) for v in value)
    if not all(math.isfinite(v) for v in (x, y, dx, dy)):
        raise ApiError(400, "'start' has a value that is not a finite number")
    if not (0.0 <= x <= 1.0 and 0.0 <= y <= 1.0):
        raise ApiError(400, f"the start point ({x:g}, {y:g}) must lie in [0, 1] x [0, 1]")
    norm = math.hypot(dx, dy)
    if norm < 1e-9:
        raise ApiError(400, "the start direction (dx, dy) must not be zero")
    return x, y, dx / norm, dy / norm


def parse_polarity(body: dict[str, Any]) -> str:
    value = body.get("polarity", "auto")
    if value not in POLARITIES:
        raise ApiError(400, f"'polarity' must be one of {', '.join(POLARITIES)}")
    return str(value)


@dataclass
class Job:
    grammar: GrammarChoice
    guide: GuideChoice | None
    target: Target
    particles: int
    seed: int


def parse_grow(body: dict[str, Any], config: WebConfig) -> Job:
    """A validated job from a /api/grow request, or an ApiError saying what is wrong."""
    from ngpm_runtime.image.targets import Target, auto_start, mask_from_image

    unknown = sorted(set(body) - set(GROW_KEYS))
    if unknown:
        raise ApiError(
            400, f"unknown field(s): {', '.join(unknown)} (expected {', '.join(GROW_KEYS)})"
        )
    if "image" not in body:
        raise ApiError(400, "'image' is missing: draw a shape or upload a picture")
    gid = body.get("grammar", config.grammars[0].id)
    grammar = config.grammar(gid) if isinstance(gid, str) else None
    if grammar is None:
        raise ApiError(
            400, f"unknown grammar {gid!r}; choose from {', '.join(g.id for g in config.grammars)}"
        )
    guide = None
    if "guide" not in body:
        guide = grammar.guides[0] if grammar.guides else None
    elif body["guide"] not in (None, "none"):
        guide = next((c for c in grammar.guides if c.id == body["guide"]), None)
        if guide is None:
            offer = ", ".join([c.id for c in grammar.guides] + ["null (unguided)"])
            raise ApiError(
                400,
                f"unknown guide {body['guide']!r} for grammar {grammar.id}; choose from {offer}",
            )
    lim = config.limits
    particles = _int(body, "particles", lim.default_particles, 1, lim.max_particles)
    seed = _int(body, "seed", 0, 0, 2**32 - 1)
    start = parse_start(body.get("start"))
    polarity = parse_polarity(body)
    img = decode_image(body["image"], lim)
    try:
        mask, start = mask_from_image(img, lim.target_size, polarity, "picture", start)
        target = Target(mask, start if start is not None else auto_start(mask), "picture")
    except TargetError as err:
        raise ApiError(422, target_message(err)) from None
    return Job(grammar, guide, target, particles, seed)


def target_message(err: TargetError) -> str:
    text = str(err)
    if "flat" in text or "no shape" in text:
        return "the picture holds no shape: draw one (or upload a picture) first"
    return "the " + text if text.startswith("picture: ") else text
