"""Issue 39, 8: the studio's UMAP map labels neither overlap nor leave the canvas, the first map shows progress,
and the header names the absolute folder it saves to."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import pytest

from brdfcodec.studio.browser import browser_missing_reason


def test_the_save_folder_is_shown_absolute(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    from brdfcodec.studio.catalogue import Catalogue
    from brdfcodec.studio.server import StudioServer

    monkeypatch.chdir(tmp_path)
    server = StudioServer(Catalogue(), save_dir=".", manifold_cache=tmp_path / "cache")
    assert server.save_dir == tmp_path.resolve() and server.save_dir.is_absolute()


_REASON = browser_missing_reason()


@pytest.mark.slow
@pytest.mark.skipif(_REASON is not None, reason=_REASON or "")
def test_map_labels_and_first_map_progress(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import brdfcodec.studio.manifold as manifold
    from brdfcodec.studio.browser import chromium_browser, open_studio, running_studio
    from brdfcodec.studio.catalogue import Catalogue
    from brdfcodec.studio.server import StudioServer, create_app

    real = manifold.cached_manifold

    def slow_first_map(*args: Any, **kwargs: Any) -> Any:  # a first map on a busy machine
        time.sleep(3.0)
        return real(*args, **kwargs)

    monkeypatch.setattr(manifold, "cached_manifold", slow_first_map)
    server = StudioServer(Catalogue(), save_dir=tmp_path, manifold_cache=tmp_path / "umap-cache")
    with running_studio(create_app(server)) as url, chromium_browser() as context:
        page = open_studio(context, url)
        assert str(tmp_path.resolve()) in page.text_content("#model-info")
        page.wait_for_function("document.getElementById('map-status').textContent.includes('s so far')")
        assert page.is_visible("#map-progress")
        page.wait_for_function("window.studio.explorer.map !== null", timeout=600_000)
        page.wait_for_function("window.studio.explorer.labels !== undefined")
        assert not page.is_visible("#map-progress")
        boxes = page.evaluate("window.studio.explorer.labels")
        width, height = page.evaluate("[window.studio.explorer.canvas.width, window.studio.explorer.canvas.height]")
        points = page.evaluate("window.studio.explorer.map.points.length")
        page.close()
    assert len(boxes) >= points // 3  # most materials keep a label
    for box in boxes:
        assert 0 <= box["x"] and box["x"] + box["w"] <= width and 0 <= box["y"] and box["y"] + box["h"] <= height
    for i, a in enumerate(boxes):
        for b in boxes[i + 1:]:
            apart = a["x"] + a["w"] <= b["x"] or b["x"] + b["w"] <= a["x"] or a["y"] + a["h"] <= b["y"] \
                or b["y"] + b["h"] <= a["y"]
            assert apart, (a["text"], b["text"])
