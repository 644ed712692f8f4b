"""bvae studio without a browser: the catalogue, the HTTP API (safety included), UMAP, the figure and the CLI.

The server runs for real (uvicorn in a thread, the shipped example library:
90 materials of the NBRDF proxy of MERL); requests use urllib.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("starlette", reason="the studio needs the studio extra (starlette, uvicorn)")
pytest.importorskip("uvicorn", reason="the studio needs the studio extra (starlette, uvicorn)")

from brdfcodec.examples import example_library  # noqa: E402
from brdfcodec.format.bvae import GraftRecord, LatentRecord, read_bvae  # noqa: E402
from brdfcodec.models.parameters import distinct_labels  # noqa: E402
from brdfcodec.studio.browser import running_studio  # noqa: E402
from brdfcodec.studio.catalogue import Catalogue  # noqa: E402
from brdfcodec.studio.server import MAX_BODY_BYTES, SLICE_STEP, StudioServer, create_app  # noqa: E402


@pytest.fixture(scope="session")
def umap_cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One UMAP cache for the whole session (the first fit takes ~15 s; later ones load it)."""
    return tmp_path_factory.getbasetemp() / "studio-umap-cache"


@pytest.fixture(scope="module")
def catalogue() -> Catalogue:
    return Catalogue()


@pytest.fixture(scope="module")
def save_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("studio-saves")


@pytest.fixture(scope="module")
def studio(catalogue: Catalogue, save_dir: Path, umap_cache: Path) -> Any:
    server = StudioServer(catalogue, save_dir=save_dir, manifold_cache=umap_cache)
    with running_studio(create_app(server)) as url:
        yield url


def request(url: str, body: Any = None, *, raw: bytes | None = None, headers: dict[str, str] | None = None,
            method: str | None = None) -> tuple[int, bytes, Any]:
    data = raw if raw is not None else (json.dumps(body).encode() if body is not None else None)
    head = {"Content-Type": "application/json"} if data is not None else {}
    head.update(headers or {})
    req = urllib.request.Request(url, data=data, headers=head, method=method)
    try:
        with urllib.request.urlopen(req, timeout=120) as response:
            return response.status, response.read(), response.headers
    except urllib.error.HTTPError as error:
        return error.code, error.read(), error.headers


def error_of(status: int, payload: bytes) -> str:
    assert 400 <= status < 500, (status, payload[:300])
    assert b"Traceback" not in payload and b'File "' not in payload
    return json.loads(payload)["error"]


# ------------------------------------------------------------------ catalogue


def test_catalogue_describes_the_example_library(catalogue: Catalogue) -> None:
    info = catalogue.describe()
    assert len(info["materials"]) == 90 and info["latent_dim"] == 8
    manifest = catalogue.decoder.manifest.parameters
    rows = sorted(manifest["dimensions"], key=lambda d: d["dim"])
    assert info["labels"] == distinct_labels(rows)
    assert len(set(info["labels"])) == 8  # one name per slider (issue 41)
    assert [d.get("factor") for d in rows[:7]] == ["albedo", "hue", "specular", "roughness", "grazing", "sheen",
                                                   "metallic"]  # the shipped latent is aligned (spec/model.md §7)
    assert all(label.startswith(d["label"]) for label, d in zip(info["labels"], rows, strict=True))
    assert info["colour_dims"] == list(catalogue.decoder.colour_dims)
    assert info["slider_range"] >= 3.0
    assert all(abs(v) <= info["slider_range"] for m in info["materials"] for v in m["mu"])
    assert "/" not in "".join(m["id"] for m in info["materials"])  # one library: plain names


def test_several_libraries_get_prefixed_ids(tmp_path: Path) -> None:
    copy = tmp_path / "nbrdf-proxy-90.bvae"
    copy.write_bytes(example_library().read_bytes())
    both = Catalogue([example_library(), copy])
    assert len(both.materials) == 180
    assert "nbrdf-proxy-90/gold-paint" in both.materials and "nbrdf-proxy-90-2/gold-paint" in both.materials


def test_catalogue_refuses_unknown_names_and_bad_codes(catalogue: Catalogue) -> None:
    with pytest.raises(ValueError, match="no material"):
        catalogue.record("../../etc/passwd")
    for bad in ([0.0] * 7, [float("nan")] + [0.0] * 7, [1e9] + [0.0] * 7, ["1"] * 8, [True] * 8, "zeros"):
        with pytest.raises(ValueError):
            catalogue.parse_code(bad)


# ------------------------------------------------------------------ API


def test_decode_returns_the_decoders_kept_slices(studio: str, catalogue: Catalogue) -> None:
    record = catalogue.record("gold-paint")
    body = {"z": [float(v) for v in record.mu], "graft": None, "base": "gold-paint"}  # the material, not an edit
    status, payload, headers = request(f"{studio}/api/decode", body)
    assert status == 200 and headers["Content-Type"] == "application/octet-stream"
    sent = np.frombuffer(payload, dtype="<u2").reshape(63, 90, 90) * SLICE_STEP
    expected = np.clip(catalogue.decoder.mapped_record(record), 0.0, 5.0)
    assert np.abs(sent - expected).max() <= SLICE_STEP / 2 + 1e-6
    assert float(headers["X-Decode-Ms"]) > 0


def test_decode_of_a_graft_uses_the_second_code(studio: str, catalogue: Catalogue) -> None:
    record = catalogue.record("green-acrylic")
    graft = [1.5, -1.0]
    status, payload, _ = request(f"{studio}/api/decode", {"z": [float(v) for v in record.mu], "graft": graft})
    assert status == 200
    expected = catalogue.decoder.mapped_record(
        GraftRecord("g", record.mu, record.sigma, catalogue.colour_dims, np.asarray(graft, np.float32),
                    {"edit": {"op": "studio"}}))  # a graft is an edit: decoded with the guard and the bound
    sent = np.frombuffer(payload, dtype="<u2").reshape(63, 90, 90) * SLICE_STEP
    assert np.abs(sent - np.clip(expected, 0, 5)).max() <= SLICE_STEP / 2 + 1e-6


@pytest.mark.parametrize(("body", "status", "fragment"), [
    ({"z": [0.0] * 3}, 400, "list of 8 numbers"),
    ({"z": [0.0] * 8, "graft": [1.0]}, 400, "graft must be a list of 2"),
    ({"z": [1e6] * 8}, 400, "within"),
    ({"z": [0.0] * 8, "base": "/etc/passwd"}, 404, "no material"),
    ([1, 2, 3], 400, "JSON object"),
])
def test_bad_decode_requests_get_4xx_messages(studio: str, body: Any, status: int, fragment: str) -> None:
    got, payload, _ = request(f"{studio}/api/decode", body)
    assert got == status
    assert fragment in error_of(got, payload)


def test_non_json_oversized_and_foreign_host_requests_are_refused(studio: str) -> None:
    status, payload, _ = request(f"{studio}/api/decode", raw=b"z=1", headers={"Content-Type": "text/plain"})
    assert status == 415 and "application/json" in error_of(status, payload)
    status, payload, _ = request(f"{studio}/api/decode", raw=b"{" + b" " * (MAX_BODY_BYTES + 10) + b"}")
    assert status == 413 and "larger than" in error_of(status, payload)
    status, payload, _ = request(f"{studio}/api/decode", raw=b'{"z": [NaN, 0, 0, 0, 0, 0, 0, 0]}')
    assert "finite" in error_of(status, payload)
    status, payload, _ = request(f"{studio}/api/decode", raw=b"{not json")
    assert "not valid JSON" in error_of(status, payload)
    status, payload, _ = request(f"{studio}/api/library", headers={"Host": "attacker.example"})
    assert status == 400  # no DNS rebinding onto the local server
    status, payload, _ = request(f"{studio}/api/thumbnail?id=..%2F..%2Fetc%2Fpasswd")
    assert status == 404 and "no material" in error_of(status, payload)
    status, payload, _ = request(f"{studio}/static/../server.py")
    assert status == 404


def test_library_mask_thumbnail_and_environment(studio: str) -> None:
    status, payload, _ = request(f"{studio}/api/library")
    info = json.loads(payload)
    assert status == 200 and len(info["materials"]) == 90 and info["environments"] == ["sky"]
    status, payload, _ = request(f"{studio}/api/mask")
    from brdfcodec.representation.mask import horizon_mask

    bits = np.unpackbits(np.frombuffer(payload, np.uint8), bitorder="little")[: 90 * 90 * 180]
    assert np.array_equal(bits.reshape(90, 90, 180).astype(bool), horizon_mask())
    status, payload, headers = request(f"{studio}/api/thumbnail?id=gold-paint")
    assert status == 200 and payload[:8] == b"\x89PNG\r\n\x1a\n"
    status, payload, _ = request(f"{studio}/api/render-environment",
                                 {"z": [0.0] * 8, "graft": None, "env": "sky", "exposure": 1.0})
    assert status == 200 and payload[:4] == b"\x89PNG"
    status, payload, _ = request(f"{studio}/api/render-environment",
                                 {"z": [0.0] * 8, "env": "/tmp/x.exr", "exposure": 1.0})
    assert "unknown environment" in error_of(status, payload)


def save_body(**fields: Any) -> dict[str, Any]:
    body = {"file": "edit.bvae", "name": "my-edit", "base": "gold-paint", "z": [0.5] * 8, "graft": None,
            "edit": {"source": "gold-paint", "changed": [0, 3], "b": "chrome", "t": 0.25, "dims_from_a": [3, 4]},
            "light": [-1, 1, 1], "exposure": 2.0}
    body.update(fields)
    return body


def test_save_writes_a_record_with_provenance_and_never_overwrites_unasked(studio: str, save_dir: Path) -> None:
    status, payload, _ = request(f"{studio}/api/save", save_body())
    assert status == 200, payload
    record = read_bvae(save_dir / "edit.bvae").records[0]
    assert isinstance(record, LatentRecord) and record.name == "my-edit"
    assert np.allclose(record.mu, 0.5)
    assert record.meta["edit"] == {"op": "studio", "source": "gold-paint", "changed": [0, 3], "b": "chrome",
                                   "t": 0.25, "dims_from_a": [3, 4]}
    before = (save_dir / "edit.bvae").read_bytes()
    status, payload, _ = request(f"{studio}/api/save", save_body(z=[-0.5] * 8))
    assert status == 409 and "already exists" in error_of(status, payload)
    assert (save_dir / "edit.bvae").read_bytes() == before
    status, payload, _ = request(f"{studio}/api/save", save_body(z=[-0.5] * 8, overwrite=True))
    assert status == 200
    assert np.allclose(read_bvae(save_dir / "edit.bvae").records[0].mu, -0.5)
    status, payload, _ = request(f"{studio}/api/save", save_body(file="graft.bvae", graft=[1.0, 2.0]))
    grafted = read_bvae(save_dir / "graft.bvae").records[0]
    assert isinstance(grafted, GraftRecord) and np.allclose(grafted.graft_values, [1.0, 2.0])


@pytest.mark.parametrize("name", ["../escape.bvae", "/tmp/abs.bvae", ".hidden.bvae", "sub/dir.bvae", "x.txt",
                                  "a\\b.bvae", ""])
def test_save_takes_plain_file_names_only(studio: str, save_dir: Path, name: str) -> None:
    status, payload, _ = request(f"{studio}/api/save", save_body(file=name))
    assert status == 400 and "plain name" in error_of(status, payload)
    assert not (save_dir.parent / "escape.bvae").exists()


@pytest.mark.parametrize("name", ["NUL", ".hidden", "a:b", "trailing.", "cafe\u0301"])
def test_save_refuses_material_names_the_format_refuses(studio: str, save_dir: Path, name: str) -> None:
    status, payload, _ = request(f"{studio}/api/save", save_body(file="named.bvae", name=name))
    assert status == 400 and error_of(status, payload).startswith("name:")
    assert not (save_dir / "named.bvae").exists()


def test_save_checks_provenance_fields(studio: str) -> None:
    status, payload, _ = request(f"{studio}/api/save", save_body(file="p.bvae", edit={"source": "/etc/passwd"}))
    assert status == 404
    status, payload, _ = request(f"{studio}/api/save", save_body(file="p.bvae", edit={"script": "x"}))
    assert "unknown" in error_of(status, payload)


def test_exports_merl_png_and_exr(studio: str, save_dir: Path, catalogue: Catalogue) -> None:
    from brdfcodec.io.exr import read_exr_rgb
    from brdfcodec.io.merl import read_merl

    record = catalogue.record("gold-paint")
    z = [float(v) for v in record.mu]
    for name in ("gold.binary", "gold.png", "gold.exr"):
        status, payload, _ = request(f"{studio}/api/save", save_body(file=name, z=z))
        assert status == 200, payload
    merl = read_merl(save_dir / "gold.binary")
    # saved without a base material, the code is an edit: decoded with the guard and the bound (spec §6)
    expected = catalogue.decoder.decode(LatentRecord("g", record.mu, record.sigma, {"edit": {"op": "studio"}}))
    assert np.allclose(merl.values, expected, rtol=1e-5, atol=1e-6)
    from PIL import Image

    assert Image.open(save_dir / "gold.png").size == (256, 256)
    image = next(iter(read_exr_rgb(save_dir / "gold.exr").values()))
    assert image.shape == (256, 256, 3) and np.isfinite(image).all() and image.max() > 0


@pytest.mark.slow
def test_manifold_endpoint_serves_the_map(studio: str, umap_cache: Path) -> None:
    deadline = time.monotonic() + 300
    while True:
        status, payload, _ = request(f"{studio}/api/manifold")
        if status != 202 or time.monotonic() > deadline:
            break
        time.sleep(0.5)  # polling a background fit, as the page does
    assert status == 200, payload[:300]
    body = json.loads(payload)
    assert len(body["points"]) == 90 and body["grid_size"] == 49
    assert len(body["grid"]) == 49 * 49 * 8 and np.isfinite(body["grid"]).all()


# ------------------------------------------------------------------ UMAP


@pytest.mark.slow
def test_umap_inverse_transform_works_on_the_library(catalogue: Catalogue, umap_cache: Path) -> None:
    from brdfcodec.studio.manifold import cached_manifold, latent_at

    codes = catalogue.codes()
    manifold = cached_manifold(codes, catalogue.ids(), catalogue.decoder.reference.sha256, folder=umap_cache)
    assert manifold.embedding.shape == (90, 2) and np.isfinite(manifold.embedding).all()
    assert manifold.grid.shape == (49, 49, 8) and np.isfinite(manifold.grid).all()
    # Mapping each material's position back lands nearer its own code than the typical distance between codes.
    back = np.stack([latent_at(manifold, x, y) for x, y in manifold.embedding])
    own = np.linalg.norm(back - codes, axis=1)
    between = np.linalg.norm(codes[:, None] - codes[None], axis=-1)[np.triu_indices(90, 1)]
    assert np.median(own) < 0.6 * np.median(between), (np.median(own), np.median(between))  # measured 0.42
    # Neighbours on the map decode to neighbouring codes: inverse_transform is continuous on the grid.
    steps = np.linalg.norm(np.diff(manifold.grid, axis=1), axis=-1)
    assert np.median(steps) < 0.25 * np.median(between)  # measured 0.15
    from brdfcodec.studio import manifold as manifold_module

    def no_refit(*args: object, **kwargs: object) -> None:
        raise AssertionError("refitted: the cache entry was not used")

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(manifold_module, "fit_manifold", no_refit)
        again = cached_manifold(codes, catalogue.ids(), catalogue.decoder.reference.sha256, folder=umap_cache)
    assert np.array_equal(again.grid, manifold.grid) and np.array_equal(again.embedding, manifold.embedding)
    assert len(list(umap_cache.glob("*.npz"))) == 1


def test_latent_at_interpolates_the_grid_bilinearly() -> None:
    from brdfcodec.studio.manifold import ManifoldMap, latent_at

    grid = np.zeros((3, 3, 2), np.float32)
    grid[..., 0] = np.arange(3)[None, :]  # varies with x (column i)
    grid[..., 1] = np.arange(3)[:, None] * 10  # varies with y (row j)
    manifold = ManifoldMap(["a"], np.zeros((1, 2)), (0.0, 2.0, 0.0, 4.0), grid)
    assert np.allclose(latent_at(manifold, 0.5, 1.0), [0.5, 5.0])
    assert np.allclose(latent_at(manifold, 2.0, 4.0), [2.0, 20.0])
    assert np.allclose(latent_at(manifold, -5.0, 99.0), [0.0, 20.0])  # clamped to the map


@pytest.mark.slow
def test_render_umap_grid_writes_the_figure(tmp_path: Path, umap_cache: Path, monkeypatch: pytest.MonkeyPatch,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    from PIL import Image

    from brdfcodec.cli.main import main

    monkeypatch.setenv("BRDFCODEC_CACHE_DIR", str(umap_cache.parent))  # manifold.cache_folder() adds "umap"
    out = tmp_path / "umap.png"
    assert main(["render", str(example_library()), "--umap-grid", "3", "-o", str(out)]) == 0
    assert "3x3 samples" in capsys.readouterr().out
    width, height = Image.open(out).size
    assert width > height > 300
    assert main(["render", str(example_library()), "--umap-grid", "3", "-o", str(out)]) == 1  # exists, no --force
    assert main(["render", str(example_library()), "--umap-grid", "40", "-o", str(tmp_path / "b.png")]) == 1
    assert main(["render", str(example_library()), "--umap-grid", "3", "--material", "x",
                 "-o", str(tmp_path / "c.png")]) == 1
    assert "no --material" in capsys.readouterr().err


def test_figure_samples_span_the_map() -> None:
    from brdfcodec.studio.figure import sample_points

    points = sample_points((0.0, 6.0, -1.0, 1.0), 7)
    assert points.shape == (7, 7, 2)
    assert np.allclose(points[0, 0], [0.0, 1.0]) and np.allclose(points[-1, -1], [6.0, -1.0])


# ------------------------------------------------------------------ CLI


def test_cli_studio_rejects_bad_arguments(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from brdfcodec.cli.main import main

    assert main(["studio", str(tmp_path / "missing.bvae")]) == 1
    assert "missing.bvae" in capsys.readouterr().err
    bad = tmp_path / "bad.bvae"
    bad.write_bytes(b"not a bvae file")
    assert main(["studio", str(bad)]) == 1
    assert main(["studio", "--port", "70000"]) == 1
    assert main(["studio", "--save-dir", str(tmp_path / "nowhere")]) == 1
    assert "Traceback" not in capsys.readouterr().err


@pytest.mark.slow
def test_cli_studio_serves_on_localhost(tmp_path: Path) -> None:
    env = {**os.environ, "BRDFCODEC_CACHE_DIR": str(tmp_path / "cache"), "OMP_NUM_THREADS": "1"}
    process = subprocess.Popen([sys.executable, "-m", "brdfcodec", "studio", "--port", "0", "--save-dir",
                                str(tmp_path)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        line = process.stdout.readline() if process.stdout else ""
        assert "http://127.0.0.1:" in line, line
        url = line.split("open ")[1].split()[0].rstrip("/")
        status, payload, _ = request(f"{url}/")
        assert status == 200 and b"bvae studio" in payload and b"https://" not in payload  # nothing from the internet
        status, payload, _ = request(f"{url}/api/library")
        assert status == 200 and len(json.loads(payload)["materials"]) == 90
    finally:
        process.terminate()
        process.wait(timeout=60)
        if process.stdout:
            process.stdout.close()


def test_front_end_ships_in_the_package_and_loads_nothing_from_outside() -> None:
    from brdfcodec.studio.server import static_folder

    files = {p.name: p.read_text() for p in static_folder().iterdir()}
    assert {"index.html", "studio.js", "render.js", "studio.css"} <= files.keys()
    for text in files.values():
        assert "http://" not in text and "https://" not in text and "//cdn" not in text


@pytest.mark.slow
def test_user_environment_map_is_offered_by_name_only(tmp_path: Path, catalogue: Catalogue) -> None:
    from brdfcodec.io.exr import write_exr_rgb

    latlong = np.ones((16, 32, 3), np.float32)
    latlong[:8] *= np.array([0.4, 0.6, 1.0], np.float32)  # blue upper half
    env_path = tmp_path / "studio-env.exr"
    write_exr_rgb(env_path, latlong)
    server = StudioServer(catalogue, save_dir=tmp_path, environment=env_path)
    with running_studio(create_app(server)) as url:
        info = json.loads(request(f"{url}/api/library")[1])
        assert info["environments"] == ["sky", "map"] and info["environment_name"] == "studio-env.exr"
        assert str(tmp_path) not in json.dumps(info["environments"])
        sky = request(f"{url}/api/render-environment", {"z": [0.0] * 8, "env": "sky", "exposure": 1.0})
        own = request(f"{url}/api/render-environment", {"z": [0.0] * 8, "env": "map", "exposure": 1.0})
        assert sky[0] == own[0] == 200 and sky[1] != own[1]
        status, payload, _ = request(f"{url}/api/render-environment", {"z": [0.0] * 8, "env": "map", "exposure": -1})
        assert "exposure" in error_of(status, payload)
