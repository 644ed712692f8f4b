"""Studio, third hardening pass (issue 49: R3-13, R3-15, R3-20; issue 52: materials left out are counted).

No browser: the application runs in uvicorn on a free localhost port (as ``bvae studio`` serves it) and is
driven with urllib and raw sockets.
"""

from __future__ import annotations

import argparse
import json
import socket
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

pytest.importorskip("starlette", reason="the studio needs the studio extra (starlette, uvicorn)")
pytest.importorskip("uvicorn", reason="the studio needs the studio extra (starlette, uvicorn)")

from brdfcodec.cli import studio_command  # noqa: E402
from brdfcodec.studio.browser import running_studio  # noqa: E402
from brdfcodec.studio.catalogue import Catalogue  # noqa: E402
from brdfcodec.studio.server import StudioServer, _light, _parse_json, create_app  # noqa: E402

HEADER_TIMEOUT = 1.0


@pytest.fixture(scope="module")
def catalogue() -> Catalogue:
    return Catalogue()


@pytest.fixture(scope="module")
def save_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("studio-saves")


@pytest.fixture(scope="module")
def studio(catalogue: Catalogue, save_dir: Path) -> Iterator[str]:
    with running_studio(create_app(StudioServer(catalogue, save_dir=save_dir)), header_timeout=HEADER_TIMEOUT) as url:
        yield url


def post(url: str, raw: bytes, headers: dict[str, str] | None = None) -> tuple[int, bytes]:
    request = urllib.request.Request(url, data=raw, headers={"Content-Type": "application/json", **(headers or {})})
    try:
        with urllib.request.urlopen(request, timeout=120) as response:
            return response.status, response.read()
    except urllib.error.HTTPError as error:
        return error.code, error.read()


def get(url: str, host: str) -> int:
    """Status of a GET with a given Host header (a raw request: urllib sets Host from the URL)."""
    port = int(url.rsplit(":", 1)[1])
    with socket.create_connection(("127.0.0.1", port), timeout=30) as connection:
        connection.sendall(f"GET /api/library HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n".encode())
        reply = b""
        while chunk := connection.recv(65536):
            reply += chunk
    return int(reply.split(b" ", 2)[1])


# --------------------------------------------------------------------------- R3-15: request bodies


@pytest.mark.parametrize("light", [[1e308, 1e308, 1e308], [1e-320, 0, 0], [-1e308, 5e-324, 1]])
def test_extreme_light_directions_are_directions(light: list[float], studio: str, save_dir: Path,
                                                 catalogue: Catalogue) -> None:
    """[1e308, 1e308, 1e308] overflowed the norm and [1e-320, 0, 0] underflowed it: a 500 "internal error
    (ValueError)". Any finite non-zero vector is a direction; it is normalised without overflow."""
    name = f"light{abs(hash(tuple(light))) % 10**6}.png"
    body = {"file": name, "light": light, "exposure": 1, "z": [0.0] * catalogue.latent_dim}
    status, payload = post(f"{studio}/api/save", json.dumps(body).encode())
    assert status == 200, payload[:300]
    assert (save_dir / name).stat().st_size > 0
    unit = np.array(_light(light))
    assert np.isfinite(unit).all() and abs(np.linalg.norm(unit) - 1) < 1e-12
    expected = np.sign(light) * (np.abs(light) == np.abs(light).max())
    assert np.allclose(unit, expected / np.linalg.norm(expected))


@pytest.mark.parametrize("light", [[0, 0, 0], [1, 2], [1, 2, "3"], [True, 0, 1], "up"])
def test_bad_light_is_a_400_with_a_message(light: Any, studio: str) -> None:
    body = {"file": "bad.png", "light": light, "exposure": 1, "z": [0.0] * 8}
    status, payload = post(f"{studio}/api/save", json.dumps(body).encode())
    assert status == 400 and "light must be" in json.loads(payload)["error"]


def test_non_finite_light_is_refused_before_json(studio: str) -> None:
    status, payload = post(f"{studio}/api/save", b'{"file": "bad.png", "light": [1e400, 0, 1], "exposure": 1}')
    assert status == 400 and "not finite" in json.loads(payload)["error"]


def test_duplicate_keys_are_refused(studio: str, catalogue: Catalogue) -> None:
    """I-JSON: a key given twice was accepted (the last one won), unlike in a .bvae file's metadata."""
    zeros, ones = [0.0] * catalogue.latent_dim, [1.0] * catalogue.latent_dim
    raw = f'{{"z": {json.dumps(ones)}, "z": {json.dumps(zeros)}}}'.encode()
    status, payload = post(f"{studio}/api/decode", raw)
    assert status == 400 and "duplicate key 'z'" in json.loads(payload)["error"]
    status, _ = post(f"{studio}/api/decode", json.dumps({"z": zeros}).encode())
    assert status == 200  # the same body without the repeat
    nested = b'{"file": "x.png", "edit": {"op": 1, "op": 2}}'
    status, payload = post(f"{studio}/api/save", nested)
    assert status == 400 and "duplicate key 'op'" in json.loads(payload)["error"]


@pytest.mark.parametrize("text", [r'"\ud800"', r'"a\udfffb"', r'"\ude00\ud83d"'])
def test_lone_surrogates_are_refused(text: str, studio: str) -> None:
    with pytest.raises(ValueError, match="surrogate"):
        _parse_json(f'{{"file": {text}}}'.encode())
    with pytest.raises(ValueError, match="surrogate"):
        _parse_json(f'{{{text}: 1}}'.encode())  # in a key too
    status, payload = post(f"{studio}/api/save", f'{{"file": {text}, "exposure": 1}}'.encode())
    assert status == 400 and "surrogate" in json.loads(payload)["error"]


def test_surrogate_pairs_and_ordinary_json_still_parse() -> None:
    assert _parse_json(r'{"name": "\ud83d\ude00", "a": {"b": [1, 2.5]}}'.encode()) == {"name": "😀",
                                                                                        "a": {"b": [1, 2.5]}}


# --------------------------------------------------------------------------- R3-20: slow header lines


def _read_until_closed(connection: socket.socket, limit: float) -> tuple[bytes, float]:
    start, reply = time.monotonic(), b""
    connection.settimeout(limit)
    try:
        while chunk := connection.recv(65536):
            reply += chunk
    except (TimeoutError, ConnectionResetError):
        pass
    return reply, time.monotonic() - start


def test_slow_header_lines_time_out(studio: str) -> None:
    """One header line every 0.3 s: the connection was still open after 20 s. Now a 408 and a closed
    connection once the header block has taken longer than the header timeout."""
    port = int(studio.rsplit(":", 1)[1])
    with socket.create_connection(("127.0.0.1", port), timeout=30) as connection:
        start = time.monotonic()
        connection.sendall(b"GET /api/library HTTP/1.1\r\nHost: 127.0.0.1\r\n")
        closed = False
        for i in range(20):  # 6 s of header lines, far past the 1 s deadline
            time.sleep(0.3)
            try:
                connection.sendall(f"X-Slow-{i}: 1\r\n".encode())
            except (BrokenPipeError, ConnectionResetError):
                closed = True
                break
        reply, _ = _read_until_closed(connection, 5.0)
        elapsed = time.monotonic() - start
    assert reply.startswith(b"HTTP/1.1 408"), reply[:100]
    assert closed or elapsed < 8.0
    assert b"did not arrive in time" in reply


def test_silent_connection_times_out(studio: str) -> None:
    port = int(studio.rsplit(":", 1)[1])
    with socket.create_connection(("127.0.0.1", port), timeout=30) as connection:
        reply, elapsed = _read_until_closed(connection, 10.0)
    assert reply.startswith(b"HTTP/1.1 408") and elapsed < HEADER_TIMEOUT + 3.0


@pytest.mark.slow
def test_prompt_requests_and_kept_alive_connections_are_served(studio: str) -> None:
    """The deadline covers each request's header block, not the connection: a second request on a kept-alive
    connection is served, and a slow second request is timed out like a first one."""
    port = int(studio.rsplit(":", 1)[1])
    request = b"GET /api/mask HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"
    with socket.create_connection(("127.0.0.1", port), timeout=30) as connection:
        for _ in range(2):
            connection.sendall(request)
            reply = b""
            while b"\r\n\r\n" not in reply:
                reply += connection.recv(65536)
            assert reply.startswith(b"HTTP/1.1 200"), reply[:100]
            head, _, body = reply.partition(b"\r\n\r\n")
            length = int(next(line.split(b":")[1] for line in head.split(b"\r\n")
                               if line.lower().startswith(b"content-length")))
            while len(body) < length:
                body += connection.recv(65536)
            time.sleep(HEADER_TIMEOUT * 0.6)  # idle between requests is the keep-alive timeout's business
        connection.sendall(b"GET /api/mask HTTP/1.1\r\n")  # a third request that never finishes its headers
        reply, elapsed = _read_until_closed(connection, 10.0)
    assert reply.startswith(b"HTTP/1.1 408") and elapsed < HEADER_TIMEOUT + 3.0


def test_header_timeout_must_be_positive() -> None:
    from brdfcodec.studio.http_guard import header_deadline_protocol

    with pytest.raises(ValueError, match="positive"):
        header_deadline_protocol(object, 0.0)  # type: ignore[arg-type]


# --------------------------------------------------------------------------- R3-13: public binds


def test_public_bind_keeps_a_host_allow_list() -> None:
    """A non-loopback bind set the allowed hosts to '*' (any Host: DNS rebinding from any page)."""
    hosts = studio_command._allowed_hosts("0.0.0.0")
    assert hosts is not None and "*" not in hosts
    assert {"127.0.0.1", "localhost", "[::1]", socket.gethostname()} <= set(hosts)
    bound = studio_command._allowed_hosts("192.0.2.7")
    assert bound is not None and "192.0.2.7" in bound and "*" not in bound
    assert "[2001:db8::1]" in (studio_command._allowed_hosts("2001:db8::1") or [])
    assert studio_command._allowed_hosts("127.0.0.1") is None  # the application's localhost default
    assert "*" in (studio_command._allowed_hosts("0.0.0.0", ["*"]) or [])  # only when asked for
    assert "studio.example" in (studio_command._allowed_hosts("0.0.0.0", ["studio.example"]) or [])


def test_public_bind_refuses_other_host_headers(catalogue: Catalogue, tmp_path: Path) -> None:
    """The red-team's request (Host: evil.com, overwrite a saved file) is refused with 400 on a public bind's
    allow-list; the machine's own name is served."""
    app = create_app(StudioServer(catalogue, save_dir=tmp_path),
                     allowed_hosts=studio_command._allowed_hosts("0.0.0.0"))
    with running_studio(app) as url:
        assert get(url, "evil.com") == 400
        assert get(url, f"evil.com:{url.rsplit(':', 1)[1]}") == 400
        assert get(url, socket.gethostname()) == 200
        assert get(url, f"localhost:{url.rsplit(':', 1)[1]}") == 200


def test_public_bind_saves_only_where_told(catalogue: Catalogue, tmp_path: Path,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """The default save folder was the current folder whatever the bind; on a public bind saving is now off
    unless --save-dir is given (403 with the reason)."""
    parser = argparse.ArgumentParser()
    studio_command.register(parser.add_subparsers())
    public = parser.parse_args(["studio", "--host", "0.0.0.0"])
    assert studio_command._save_dir(public) is None
    assert studio_command._save_dir(parser.parse_args(["studio"])) == Path(".")
    chosen = parser.parse_args(["studio", "--host", "0.0.0.0", "--save-dir", str(tmp_path)])
    assert studio_command._save_dir(chosen) == tmp_path
    monkeypatch.chdir(tmp_path)
    with running_studio(create_app(StudioServer(catalogue, save_dir=None))) as url:
        status, payload = post(f"{url}/api/save", json.dumps({"file": "x.bvae", "z": [0.0] * 8}).encode())
        info = json.loads(urllib.request.urlopen(f"{url}/api/library", timeout=60).read())
    assert status == 403 and "--save-dir" in json.loads(payload)["error"]
    assert info["save_dir"] is None
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- issue 52: materials left out


def test_startup_line_counts_the_materials_left_out() -> None:
    """Records without a latent code are left out of the studio; the start-up line says how many and why."""
    everything = SimpleNamespace(materials={"a": 1, "b": 2}, without_latent=[])
    assert studio_command._materials_line(everything) == "2 materials"
    some = SimpleNamespace(materials={"a": 1, "b": 2}, without_latent=["lib/c", "lib/d", "lib/e"])
    line = studio_command._materials_line(some)
    assert line.startswith("2 of 5 materials (3 left out:") and "no latent code" in line
    assert "--latent always" in line

