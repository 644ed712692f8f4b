"""The studio's web application (Starlette): a JSON and binary API plus the static front-end.

Design (see the documentation's studio page, ``docs/studio.md``):

* **The preview is rendered in the browser.** The server decodes a latent
  code to the 21 kept φd slices (63×90×90, sent as uint16: 1 MB) and the page
  renders the 256×256 sphere from them in JavaScript
  (nearest-bin lookup, slice interpolation and unmapping as
  :func:`brdfcodec.render.preview.render_sphere` does). A server-side render of the
  same preview (full decode + ``render_sphere``) costs several times the decode before any
  PNG encoding and transfer, and a light drag would need the server again;
  in the browser a light drag costs no request at all.
* **No stale frames**: the page keeps at most one decode request in flight
  per preview and sends only the newest slider state when it returns.
* **Per-tab state lives in the tab**: every request carries the full edit
  state (code, graft values, base material); the server keeps no edit state,
  so two tabs cannot corrupt each other. Caches (thumbnails, the UMAP map)
  depend on the opened libraries only.
* **Safe by default**: the client names materials by id (never a path),
  request bodies are capped at :data:`MAX_BODY_BYTES`, bad requests get a
  4xx JSON ``{"error": message}``, unexpected failures a 500 with the error's
  type only, never a traceback. Only ``Host`` headers of the bound address
  are served (no DNS rebinding), and state-changing requests must be JSON
  (which a cross-site form cannot send). Saving writes plain file names into
  the save folder and refuses to replace a file unless the request says so
  (the page asks the user first).
"""

from __future__ import annotations

import asyncio
import io
import json
import math
import re
import threading
import time
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException
from starlette.middleware import Middleware
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from brdfcodec.conventions import MAPPED_MAX
from brdfcodec.studio import StudioError
from brdfcodec.studio.catalogue import Catalogue

__all__ = ["BODY_TIMEOUT_S", "MAX_BODY_BYTES", "SLICE_STEP", "StudioServer", "create_app", "quantise_slices",
           "static_folder"]

#: Largest request body accepted, bytes.
MAX_BODY_BYTES = 64 * 1024
#: Longest a request body may take to arrive, seconds (a slow sender cannot hold a connection for long).
BODY_TIMEOUT_S = 10.0
#: Deepest nesting of JSON arrays and objects in a request body.
MAX_JSON_DEPTH = 32
_LARGEST_EXACT = (1 << 53) - 1
#: Plain output names: letters, digits, '.', '_', '-', a known suffix; no folders, no leading dot.
_FILE_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9._-]{0,120}\.(bvae|binary|png|exr)$")
_MATERIAL_NAME = re.compile(r"^[^\x00-\x1f\x7f/\\]{1,200}$")
_ENV_SIZE = 128
_THUMB_SIZE = 64


def static_folder() -> Path:
    """The front-end files shipped in the package."""
    return Path(str(resources.files("brdfcodec.studio").joinpath("static")))


class StudioServer:
    """State shared by all requests: the catalogue, environments, caches, the save folder.

    Parameters
    ----------
    catalogue : Catalogue
    save_dir : path-like or None
        Folder where saved and exported files go; ``None`` turns saving off (``/api/save`` answers 403), as
        ``bvae studio`` does on a public address without ``--save-dir``.
    environment : path-like, optional
        A lat-long EXR offered as the "map" environment besides the built-in sky.
    manifold_cache : path-like, optional
        Folder of the UMAP cache (default: the user cache folder).
    """

    def __init__(self, catalogue: Catalogue, *, save_dir: str | Path | None = ".",
                 environment: str | Path | None = None, manifold_cache: str | Path | None = None) -> None:
        from brdfcodec.render.preview import Environment, sky_environment

        self.catalogue = catalogue
        self.save_dir = None if save_dir is None else Path(save_dir).resolve()  # shown: absolute, never "."
        if self.save_dir is not None and not self.save_dir.is_dir():
            raise NotADirectoryError(f"{self.save_dir}: the save folder does not exist")
        self.environments: dict[str, Any] = {"sky": sky_environment()}
        if environment is not None:
            from brdfcodec.io.exr import read_exr_rgb

            parts = read_exr_rgb(environment)
            self.environments["map"] = Environment.from_latlong(next(iter(parts.values())))
            self.environment_name = Path(environment).name
        else:
            self.environment_name = None
        self.manifold_cache = Path(manifold_cache) if manifold_cache is not None else None
        self._decode_lock = threading.Lock()
        self._thumbnails: dict[str, bytes] = {}
        self._manifold: Any = None
        self._manifold_error: str | None = None
        self._manifold_thread: threading.Thread | None = None
        self._manifold_lock = threading.Lock()

    # ------------------------------------------------------------------ decoding

    def decode_slices(self, body: dict[str, Any]) -> tuple[bytes, float]:
        """Kept slices of the requested code, quantised (see :func:`quantise_slices`), and the decode time in ms."""
        record = self.catalogue.edited_record(body)
        start = time.perf_counter()
        with self._decode_lock:
            mapped = self.catalogue.decoder.mapped_record(record)
        return quantise_slices(mapped), (time.perf_counter() - start) * 1e3

    def decoded(self, body: dict[str, Any]) -> Any:
        from brdfcodec.codec import DecodedMaterial

        record = self.catalogue.edited_record(body)
        with self._decode_lock:
            material = DecodedMaterial(record, self.catalogue.decoder)
            material.physical()
        return material

    def render_environment_png(self, body: dict[str, Any]) -> bytes:
        """The code rendered under an environment ("sky" or "map"), PNG at the client's exposure."""
        from brdfcodec.render.images import encode_srgb
        from brdfcodec.render.preview import render_sphere_environment

        name = body.get("env")
        if name not in self.environments:
            raise StudioError(f"unknown environment {str(name)[:40]!r}; available: {', '.join(self.environments)}")
        exposure = _exposure(body.get("exposure"))
        image = render_sphere_environment(self.decoded(body), self.environments[name], size=_ENV_SIZE)
        return _png(encode_srgb(image, exposure=exposure))

    def thumbnail(self, material_id: str) -> bytes:
        """A small sphere render of a library material (PNG, cached; exposure set per material)."""
        if material_id not in self._thumbnails:
            from brdfcodec.codec import DecodedMaterial
            from brdfcodec.render.images import auto_exposure, encode_srgb
            from brdfcodec.render.preview import render_sphere

            record = self.catalogue.record(material_id)
            with self._decode_lock:
                image = render_sphere(DecodedMaterial(record, self.catalogue.decoder), size=_THUMB_SIZE)
            self._thumbnails[material_id] = _png(encode_srgb(image, exposure=auto_exposure(image)))
        return self._thumbnails[material_id]

    # ------------------------------------------------------------------ manifold

    def start_manifold(self) -> None:
        """Fit (or load) the UMAP map in a background thread, once."""
        with self._manifold_lock:
            if self._manifold_thread is None:
                self._manifold_thread = threading.Thread(target=self._fit_manifold, name="studio-umap", daemon=True)
                self._manifold_thread.start()

    def _fit_manifold(self) -> None:
        from brdfcodec.studio.manifold import cached_manifold

        try:
            self._manifold = cached_manifold(self.catalogue.codes(), self.catalogue.ids(),
                                             self.catalogue.decoder.reference.sha256, folder=self.manifold_cache)
        except Exception as error:  # noqa: BLE001 - reported to the client as a message
            self._manifold_error = f"the UMAP map could not be made: {type(error).__name__}: {error}"

    def manifold_state(self) -> tuple[int, dict[str, Any]]:
        """(HTTP status, body): 200 with the map, 202 while fitting, 503 with the reason if it failed."""
        self.start_manifold()
        if self._manifold is not None:
            return 200, self._manifold.as_json()
        if self._manifold_error is not None:
            return 503, {"error": self._manifold_error}
        return 202, {"status": "computing the UMAP map (a few seconds the first time; cached afterwards)"}

    # ------------------------------------------------------------------ saving

    def save(self, body: dict[str, Any]) -> dict[str, Any]:
        """Write the edited material: ``.bvae`` (record with provenance), MERL ``.binary``, ``.png`` or ``.exr``."""
        from brdfcodec.format.bvae import GraftRecord, LatentRecord

        if self.save_dir is None:
            raise StudioError("saving is off: this studio was started on a public address without --save-dir "
                              "(start it with --save-dir FOLDER to save)", status=403)

        file_name = body.get("file")
        if not isinstance(file_name, str) or not _FILE_NAME.fullmatch(file_name):  # fullmatch: "$" allows a "\n"
            raise StudioError("file must be a plain name (letters, digits, . _ -) ending in .bvae, .binary, .png or "
                              ".exr; folders are not allowed")
        name = body.get("name", "studio-edit")
        if not isinstance(name, str) or not _MATERIAL_NAME.fullmatch(name):
            raise StudioError("name must be 1 to 200 characters without control characters or slashes")
        from brdfcodec.format.material_names import check_material_name

        for label, value in (("file", file_name), ("name", name)):
            try:  # the file format's rules (spec/bvae-format.md §4.3): "NUL", "CON.bvae", ".x", "a:b" ...
                check_material_name(value)
            except ValueError as error:
                raise StudioError(f"{label}: {error}") from None
        overwrite = body.get("overwrite") is True
        target = self.save_dir / file_name
        if target.exists() and not overwrite:
            raise StudioError(f"{file_name} already exists in the save folder; confirm to replace it", status=409)
        record = self.catalogue.edited_record(body, name=name)
        edit = _provenance(body.get("edit"), self.catalogue)
        meta = {"edit": edit}
        if isinstance(record, GraftRecord):
            record = GraftRecord(name, record.mu, record.sigma, record.graft_dims, record.graft_values, meta)
        elif getattr(record, "basis", None) is not None or getattr(record, "detail", None) is not None:
            import dataclasses

            record = dataclasses.replace(record, name=name, meta=meta)  # a layered edit keeps its layers
        else:
            record = LatentRecord(name, record.mu, record.sigma, meta)
        suffix = target.suffix.lower()
        try:
            if suffix == ".bvae":
                from brdfcodec.format.bvae import write_bvae

                write_bvae(target, [record], self.catalogue.decoder.reference, overwrite=overwrite)
            elif suffix == ".binary":
                from brdfcodec.codec import DecodedMaterial
                from brdfcodec.io.merl import write_merl

                with self._decode_lock:
                    table = DecodedMaterial(record, self.catalogue.decoder).to_merl()
                write_merl(target, table, overwrite=overwrite)
            else:
                from brdfcodec.render.images import write_image
                from brdfcodec.render.preview import render_sphere, render_sphere_environment

                material = self.decoded(body)
                env = body.get("env")
                if env in self.environments:
                    image = render_sphere_environment(material, self.environments[env], size=256)
                else:
                    image = render_sphere(material, size=256, light=_light(body.get("light")))
                write_image(target, image, exposure=_exposure(body.get("exposure")), overwrite=overwrite)
        except FileExistsError as error:
            raise StudioError(f"{file_name} already exists in the save folder; confirm to replace it",
                              status=409) from error
        return {"saved": file_name, "bytes": target.stat().st_size, "folder": str(self.save_dir)}


#: Mapped value of one quantisation step of the slices sent to the browser.
SLICE_STEP = MAPPED_MAX / 65535.0


def quantise_slices(mapped: np.ndarray) -> bytes:
    """Mapped kept slices (63, 90, 90) as little-endian uint16 bytes, ``round(m / SLICE_STEP)``, m clamped to [0, 5].

    The step is 7.6e-5 in the mapped domain, a relative error of at most 1.8e-4
    in reflectance after unmapping; half the bytes of float32 (1 MB a decode).
    """
    clamped = np.clip(np.nan_to_num(mapped, nan=0.0), 0.0, MAPPED_MAX)
    return np.rint(clamped * np.float32(1.0 / SLICE_STEP)).astype("<u2").tobytes()


def _png(pixels: np.ndarray) -> bytes:
    from PIL import Image

    stream = io.BytesIO()
    Image.fromarray(pixels, mode="RGB").save(stream, format="PNG")
    return stream.getvalue()


def _exposure(value: object) -> float:
    if not isinstance(value, int | float) or isinstance(value, bool) or not (1e-9 < value < 1e9):
        raise StudioError("exposure must be a positive number")
    return float(value)


def _light(value: object) -> tuple[float, float, float]:
    """A light direction as a unit vector: any non-zero list of 3 finite numbers, normalised without overflow
    or underflow (scaled by its largest component first: [1e308, 1e308, 1e308] and [1e-320, 0, 0] are
    directions like any other)."""
    if (not isinstance(value, list) or len(value) != 3
            or not all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in value)
            or not any(value)):
        raise StudioError("light must be a non-zero list of 3 finite numbers (a direction towards the light)")
    vector = np.array([float(v) for v in value])
    vector = vector / np.abs(vector).max()  # components in [-1, 1], one of them ±1: the norm is in [1, √3]
    vector = vector / np.linalg.norm(vector)
    return (float(vector[0]), float(vector[1]), float(vector[2]))


_EDIT_KEYS = {"source": str, "b": str, "t": (int, float), "dims_from_a": list, "sampled": bool, "graft": bool,
              "changed": list, "manifold": list}


def _provenance(edit: object, catalogue: Catalogue) -> dict[str, Any]:
    """The edit provenance a saved record carries: ``{"op": "studio", ...}`` with checked fields only."""
    out: dict[str, Any] = {"op": "studio"}
    if edit is None:
        return out
    if not isinstance(edit, dict):
        raise StudioError("edit must be an object")
    for key, value in edit.items():
        kind = _EDIT_KEYS.get(key)
        if kind is None or not isinstance(value, kind) or isinstance(value, bool) and kind is not bool:
            raise StudioError(f"edit field {str(key)[:40]!r} is unknown or has the wrong type")
        if key in ("source", "b"):
            catalogue.record(value)  # must name a material of the opened libraries
        if isinstance(value, list) and (len(value) > 64 or not all(
                isinstance(v, int | float) and not isinstance(v, bool) for v in value)):
            raise StudioError(f"edit field {key!r} must be a short list of numbers")
        if (isinstance(value, float) and not math.isfinite(value)) or (isinstance(value, list) and not all(
                math.isfinite(v) and abs(v) <= _LARGEST_EXACT for v in value)):
            raise StudioError(f"edit field {key!r} must hold finite numbers (integers within ±(2^53 − 1))")
        out[key] = value
    return out


# ---------------------------------------------------------------------- HTTP layer


def _refuse_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a JSON number (numbers must be finite)")


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"number {text[:40]} is not finite (it overflows binary64)")
    return value


def _exact_int(text: str) -> int:
    if len(text) > 17 or abs(int(text)) > _LARGEST_EXACT:  # parsed only when short: no quadratic conversion
        raise ValueError(f"integer {text[:40]}{'…' if len(text) > 40 else ''} is beyond ±(2^53 − 1)")
    return int(text)


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """An object's members, refusing a key given twice (I-JSON; otherwise the last one silently wins)."""
    result = dict(pairs)
    if len(result) != len(pairs):
        seen: set[str] = set()
        for key, _ in pairs:
            if key in seen:
                raise ValueError(f"duplicate key {key[:40]!r} in an object")
            seen.add(key)
    return result


def _parse_json(data: bytes) -> Any:
    """JSON as I-JSON (RFC 7493) has it: finite numbers, integers exact in binary64, no key twice in an object,
    no lone surrogate escape (``"\\ud800"``: not Unicode text), at most :data:`MAX_JSON_DEPTH` levels of
    nesting (checked before parsing, so a deep body cannot exhaust the stack); the rules of the ``.bvae``
    metadata reader (:mod:`brdfcodec.format.strict_json`)."""
    depth = 0
    in_string = escaped = False
    for byte in data:  # counting brackets outside strings is exact for valid JSON
        if in_string:
            if escaped:
                escaped = False
            elif byte == 0x5C:
                escaped = True
            elif byte == 0x22:
                in_string = False
        elif byte == 0x22:
            in_string = True
        elif byte in (0x5B, 0x7B):
            depth += 1
            if depth > MAX_JSON_DEPTH:
                raise ValueError(f"nested deeper than {MAX_JSON_DEPTH} levels")
        elif byte in (0x5D, 0x7D):
            depth -= 1
    value = json.loads(data, parse_constant=_refuse_constant, parse_float=_finite_float, parse_int=_exact_int,
                       object_pairs_hook=_unique_keys)
    try:  # lone surrogates are valid JSON escapes but not Unicode text (linear: one serialisation)
        json.dumps(value, ensure_ascii=False).encode("utf-8")
    except UnicodeEncodeError:
        raise ValueError("a string holds a lone surrogate escape (not Unicode text)") from None
    return value


async def _json_body(request: Request) -> dict[str, Any]:
    """The request's JSON object, refusing bodies over :data:`MAX_BODY_BYTES`, bodies that take longer than
    :data:`BODY_TIMEOUT_S` to arrive, non-JSON content types, and JSON beyond I-JSON's rules (:func:`_parse_json`)."""
    if request.headers.get("content-type", "").split(";")[0].strip() != "application/json":
        raise StudioError("send the request as application/json", status=415)
    declared = request.headers.get("content-length")
    if declared is not None and (not declared.isdigit() or int(declared) > MAX_BODY_BYTES):
        raise StudioError(f"request body larger than {MAX_BODY_BYTES} bytes", status=413)
    chunks, size = [], 0
    try:
        async with asyncio.timeout(BODY_TIMEOUT_S):
            async for chunk in request.stream():
                size += len(chunk)
                if size > MAX_BODY_BYTES:
                    raise StudioError(f"request body larger than {MAX_BODY_BYTES} bytes", status=413)
                chunks.append(chunk)
    except TimeoutError:
        raise StudioError(f"the request body did not arrive within {BODY_TIMEOUT_S:g} s", status=408) from None
    try:
        body = _parse_json(b"".join(chunks) or b"null")
    except (ValueError, UnicodeDecodeError, RecursionError) as error:
        raise StudioError(f"the body is not valid JSON: {error}") from None
    if not isinstance(body, dict):
        raise StudioError("the body must be a JSON object")
    return body


def create_app(server: StudioServer, *, allowed_hosts: list[str] | None = None) -> Starlette:
    """The Starlette application of a :class:`StudioServer`.

    Parameters
    ----------
    allowed_hosts : list of str, optional
        ``Host`` header values served (default: localhost names only).
    """
    static = static_folder()

    async def index(request: Request) -> Response:
        return FileResponse(static / "index.html", headers={"Cache-Control": "no-store"})

    async def library(request: Request) -> Response:
        info = server.catalogue.describe()
        info["environments"] = ["sky", *(["map"] if "map" in server.environments else [])]
        info["environment_name"] = server.environment_name
        info["save_dir"] = None if server.save_dir is None else str(server.save_dir)
        return JSONResponse(info)

    async def mask(request: Request) -> Response:
        from brdfcodec.representation.mask import horizon_mask

        return Response(np.packbits(horizon_mask(), bitorder="little").tobytes(),
                        media_type="application/octet-stream", headers={"Cache-Control": "max-age=3600"})

    async def decode(request: Request) -> Response:
        body = await _json_body(request)
        data, ms = await run_in_threadpool(server.decode_slices, body)
        return Response(data, media_type="application/octet-stream", headers={"X-Decode-Ms": f"{ms:.2f}"})

    async def render_environment(request: Request) -> Response:
        body = await _json_body(request)
        return Response(await run_in_threadpool(server.render_environment_png, body), media_type="image/png")

    async def thumbnail(request: Request) -> Response:
        material_id = request.query_params.get("id")
        data = await run_in_threadpool(server.thumbnail, material_id)
        return Response(data, media_type="image/png", headers={"Cache-Control": "max-age=3600"})

    async def manifold(request: Request) -> Response:
        status, body = server.manifold_state()
        return JSONResponse(body, status_code=status)

    async def save(request: Request) -> Response:
        body = await _json_body(request)
        return JSONResponse(await run_in_threadpool(server.save, body))

    async def studio_error(request: Request, error: Exception) -> Response:
        assert isinstance(error, StudioError)
        return JSONResponse({"error": str(error)}, status_code=error.status)

    async def http_error(request: Request, error: Exception) -> Response:
        assert isinstance(error, HTTPException)
        return JSONResponse({"error": error.detail}, status_code=error.status_code)

    async def internal_error(request: Request, error: Exception) -> Response:
        return JSONResponse({"error": f"internal error ({type(error).__name__}); see the server's log"},
                            status_code=500)

    hosts = allowed_hosts or ["127.0.0.1", "localhost", "::1", "[::1]"]
    return Starlette(
        routes=[
            Route("/", index),
            Route("/api/library", library),
            Route("/api/mask", mask),
            Route("/api/decode", decode, methods=["POST"]),
            Route("/api/render-environment", render_environment, methods=["POST"]),
            Route("/api/thumbnail", thumbnail),
            Route("/api/manifold", manifold),
            Route("/api/save", save, methods=["POST"]),
            Mount("/static", app=StaticFiles(directory=static), name="static"),
        ],
        middleware=[Middleware(TrustedHostMiddleware, allowed_hosts=hosts)],
        exception_handlers={StudioError: studio_error, HTTPException: http_error, Exception: internal_error},
    )


def make_app(paths: list[str] | None = None, **options: Any) -> Starlette:
    """Shortcut for tests and ASGI servers: a catalogue, a server and its application."""
    model = options.pop("model", None)
    hosts = options.pop("allowed_hosts", None)
    return create_app(StudioServer(Catalogue(paths, model=model), **options), allowed_hosts=hosts)


