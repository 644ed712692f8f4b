"""Driving the studio in a real browser: a server in a thread, and Debian's chromium through Playwright.

Used by the browser tests, the latency benchmark and the screenshot script
(:mod:`brdfcodec.studio.screenshots`). The browser is the system's
``/usr/bin/chromium`` (``$BRDFCODEC_CHROMIUM`` overrides it) driven by
Playwright's Python API with a fresh profile; Playwright's own browser
download is not used. Synchronisation waits for the page's paint counters,
never for fixed delays.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
import threading
import time
from collections.abc import Iterator
from typing import Any

import numpy as np

CHROMIUM_FLAGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
]
#: Generous: the development machine has 2 cores shared with other work.
TIMEOUT_MS = 120_000


def chromium_path() -> str | None:
    """The system chromium, or None."""
    path = os.environ.get("BRDFCODEC_CHROMIUM", "/usr/bin/chromium")
    return path if os.path.isfile(path) and os.access(path, os.X_OK) else shutil.which("chromium")


def browser_missing_reason() -> str | None:
    """Why the browser tests cannot run here, or None when they can."""
    try:
        import playwright.sync_api  # noqa: F401
        import starlette  # noqa: F401
        import uvicorn  # noqa: F401
    except ImportError as error:
        return f"the studio's browser tests need {error.name} (pip install '.[test]')"
    if chromium_path() is None:
        return "Debian's chromium is not installed (/usr/bin/chromium; .ci/run installs it with apt-get)"
    return None


@contextlib.contextmanager
def running_studio(app: Any, *, header_timeout: float | None = None) -> Iterator[str]:
    """Serve a Starlette app with uvicorn on a free localhost port in a thread, configured as ``bvae studio``
    serves it (:func:`brdfcodec.studio.http_guard.server_config`); yields its base URL."""
    import uvicorn

    from brdfcodec.studio.http_guard import HEADER_TIMEOUT_S, server_config

    config = server_config(app, host="127.0.0.1", port=0, lifespan="off",
                           header_timeout=HEADER_TIMEOUT_S if header_timeout is None else header_timeout)
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, name="studio-test-server", daemon=True)
    thread.start()
    deadline = time.monotonic() + 60
    while not server.started:
        if not thread.is_alive() or time.monotonic() > deadline:
            raise RuntimeError("the studio server did not start")
        time.sleep(0.02)
    port = server.servers[0].sockets[0].getsockname()[1]
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(timeout=30)


@contextlib.contextmanager
def chromium_browser() -> Iterator[Any]:
    """A Playwright browser context on the system chromium with a fresh profile; closed and removed afterwards."""
    from playwright.sync_api import sync_playwright

    profile = tempfile.mkdtemp(prefix="bvae-studio-chromium-")
    try:
        with sync_playwright() as playwright:
            context = playwright.chromium.launch_persistent_context(
                profile, executable_path=chromium_path(), headless=True, args=CHROMIUM_FLAGS,
                viewport={"width": 1400, "height": 1000},
            )
            context.set_default_timeout(TIMEOUT_MS)
            try:
                yield context
            finally:
                context.close()
    finally:
        shutil.rmtree(profile, ignore_errors=True)


def open_studio(context: Any, url: str) -> Any:
    """A new page on the studio, after its first editor frame is painted."""
    page = context.new_page()
    page.goto(url)
    page.wait_for_function("window.studio && window.studio.previews.editor.paintCount >= 1")
    return page


def paint_count(page: Any, preview: str = "editor") -> int:
    return int(page.evaluate(f"window.studio.previews.{preview}.paintCount"))


def wait_for_paint_after(page: Any, count: int, preview: str = "editor") -> None:
    """Wait until the preview has painted more than ``count`` frames and has no request pending."""
    page.wait_for_function(
        f"(() => {{ const p = window.studio.previews.{preview}; "
        f"return p.paintCount > {count} && !p.inflight && p.pending === null; }})()"
    )


def set_slider(page: Any, element_id: str, value: float) -> None:
    """Set a range input and fire its ``input`` event, as a user's drag does."""
    page.evaluate(
        "([id, v]) => { const el = document.getElementById(id); el.value = String(v); "
        "el.dispatchEvent(new Event('input', {bubbles: true})); }",
        [element_id, value],
    )


def canvas_pixels(page: Any, canvas_id: str) -> np.ndarray:
    """The canvas's pixels, (H, W, 3) uint8 (read back as a lossless PNG)."""
    import base64
    import io

    from PIL import Image

    url = page.evaluate(f"document.getElementById('{canvas_id}').toDataURL('image/png')")
    data = base64.b64decode(url.split(",", 1)[1])
    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))


def srgb_to_linear(pixels: np.ndarray) -> np.ndarray:
    """8-bit sRGB to linear [0, 1] (colour-science)."""
    from brdfcodec.render.images import colour_module

    return np.asarray(colour_module().cctf_decoding(pixels / 255.0, function="sRGB"), dtype=np.float64)
