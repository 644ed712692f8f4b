"""bvae studio in a real browser: Debian's chromium driven by Playwright (Python), with the system executable.

The page's previews are rendered in the browser from the decoded kept slices;
these tests check that what is painted matches the library's own render
(:func:`brdfcodec.render.preview.render_sphere`) of the same latent within
ΔE ITP (mean) < :data:`MAX_DELTA_E_ITP` and 2 levels per 8-bit pixel, that sliders, the light and the map
cursor change it, that dragging drops stale frames, that two tabs keep their
own state, and that saving asks before replacing a file. They wait for the
page's paint counters, never for fixed delays. Material: the shipped example
library (NBRDF proxy of MERL).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from brdfcodec.studio.browser import browser_missing_reason

_REASON = browser_missing_reason()
pytestmark = [pytest.mark.skipif(_REASON is not None, reason=_REASON or ""), pytest.mark.slow]

#: Largest mean ΔE ITP between the painted preview and render_sphere of the same code (8-bit, same exposure);
#: measured 0.018–0.023 on 7 materials of the example library (8-bit quantisation).
MAX_DELTA_E_ITP = 0.1
#: 8-bit levels by which a painted pixel may differ from encode_srgb(render_sphere(...)) (measured: at most 2) ...
MAX_LEVELS = 2
#: ... on all but this fraction of the pixels (bin ties decided differently by float rounding; measured 0).
MAX_OFF_FRACTION = 0.0005


@pytest.fixture(scope="module")
def studio_env(tmp_path_factory: pytest.TempPathFactory) -> Any:
    from brdfcodec.studio.browser import chromium_browser, running_studio
    from brdfcodec.studio.catalogue import Catalogue
    from brdfcodec.studio.server import StudioServer, create_app

    catalogue = Catalogue()
    save_dir = tmp_path_factory.mktemp("browser-saves")
    cache = tmp_path_factory.getbasetemp() / "studio-umap-cache"
    server = StudioServer(catalogue, save_dir=save_dir, manifold_cache=cache)
    with running_studio(create_app(server)) as url, chromium_browser() as context:
        yield {"url": url, "context": context, "catalogue": catalogue, "save_dir": save_dir, "cache": cache}


@pytest.fixture
def page(studio_env: dict[str, Any]) -> Any:
    from brdfcodec.studio.browser import open_studio

    page = open_studio(studio_env["context"], studio_env["url"])
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    yield page
    page.close()
    assert not errors, errors


def library_render(catalogue: Any, z: list[float], light: list[float], graft: list[float] | None = None,
                   size: int = 256) -> np.ndarray:
    from brdfcodec.codec import DecodedMaterial
    from brdfcodec.format.bvae import GraftRecord, LatentRecord
    from brdfcodec.render.preview import render_sphere

    code = np.asarray(z, np.float32)
    edit = {"edit": {"op": "studio"}}  # as the studio decodes a code: with the energy bound (spec §6 step 5)
    record = (LatentRecord("r", code, np.ones(8), edit) if graft is None
              else GraftRecord("r", code, np.ones(8), catalogue.colour_dims, np.asarray(graft, np.float32), edit))
    return render_sphere(DecodedMaterial(record, catalogue.decoder), size=size, light=light)


def painted_error(page: Any, catalogue: Any, preview: str) -> float:
    """Mean ΔE ITP between the painted canvas and render_sphere of the code the preview shows (same exposure).

    Also checks the 8-bit pixels: within :data:`MAX_LEVELS` of ``encode_srgb(render_sphere(...))`` on all but
    :data:`MAX_OFF_FRACTION` of them (an off-by-one φd bin already moves 0.1–3 % of them by up to 66 levels).
    """
    from brdfcodec.render.image_metrics import image_error
    from brdfcodec.render.images import encode_srgb
    from brdfcodec.studio.browser import canvas_pixels, srgb_to_linear

    shown = page.evaluate(f"window.studio.previews.{preview}.shownState")
    light = page.evaluate(f"window.studio.previews.{preview}.light")
    exposure = page.evaluate(f"(p => p.exposure * p.exposureScale)(window.studio.previews.{preview})")
    linear = library_render(catalogue, shown["z"], light, shown["graft"])
    painted = canvas_pixels(page, f"{preview}-canvas")
    off = np.abs(encode_srgb(linear, exposure=exposure).astype(int) - painted.astype(int)).max(-1) > MAX_LEVELS
    assert off.mean() <= MAX_OFF_FRACTION, f"{off.mean():.2%} of the pixels differ by more than {MAX_LEVELS} levels"
    reference = np.clip(linear * exposure, 0.0, 1.0)
    return image_error(reference, srgb_to_linear(painted), exposure=1.0).delta_e_itp_mean


def test_editor_paints_the_library_render_and_sliders_change_it(page: Any, studio_env: dict[str, Any]) -> None:
    from brdfcodec.studio.browser import canvas_pixels, paint_count, set_slider, wait_for_paint_after

    catalogue = studio_env["catalogue"]
    first = catalogue.materials[catalogue.ids()[0]].record
    shown = page.evaluate("window.studio.previews.editor.shownState")
    assert np.allclose(shown["z"], first.mu, atol=1e-6)
    assert painted_error(page, catalogue, "editor") < MAX_DELTA_E_ITP
    before = canvas_pixels(page, "editor-canvas")
    count = paint_count(page)
    set_slider(page, "z1", -2.5)  # z2 (element ids are 0-based): hue
    wait_for_paint_after(page, count)
    after = canvas_pixels(page, "editor-canvas")
    assert np.abs(after.astype(int) - before.astype(int)).mean() > 2.0
    assert page.evaluate("window.studio.previews.editor.shownState.z[1]") == pytest.approx(-2.5)
    assert painted_error(page, catalogue, "editor") < MAX_DELTA_E_ITP
    assert page.evaluate("window.studio.editor.state.edit.changed") == [1]


def test_material_choice_graft_and_interpolation(page: Any, studio_env: dict[str, Any]) -> None:
    from brdfcodec.studio.browser import paint_count, set_slider, wait_for_paint_after

    catalogue = studio_env["catalogue"]
    count = paint_count(page)
    page.select_option("#material", "green-acrylic")
    wait_for_paint_after(page, count)
    assert np.allclose(page.evaluate("window.studio.previews.editor.shownState.z"),
                       catalogue.record("green-acrylic").mu, atol=1e-6)
    count = paint_count(page)
    page.check("#graft")
    wait_for_paint_after(page, count)
    count = paint_count(page)
    set_slider(page, "g0", 2.0)
    wait_for_paint_after(page, count)
    graft = page.evaluate("window.studio.previews.editor.shownState.graft")
    assert graft[0] == pytest.approx(2.0) and len(graft) == 2
    assert painted_error(page, catalogue, "editor") < MAX_DELTA_E_ITP

    # Interpolation towards chrome, z4 and z5 kept from A (per-factor toggles).
    page.check("#from-a-3")
    page.check("#from-a-4")
    count = paint_count(page)
    page.select_option("#material-b", "chrome")
    set_slider(page, "interp-t", 0.75)
    wait_for_paint_after(page, count)
    a, b = catalogue.record("green-acrylic").mu, catalogue.record("chrome").mu
    expected = 0.25 * a + 0.75 * b
    expected[[3, 4]] = a[[3, 4]]
    assert np.allclose(page.evaluate("window.studio.editor.state.z"), expected, atol=1e-5)
    wait_for_paint_after(page, paint_count(page) - 1)
    assert np.allclose(page.evaluate("window.studio.previews.editor.shownState.z"), expected, atol=1e-5)


def test_dragging_drops_stale_frames(page: Any, studio_env: dict[str, Any]) -> None:
    from brdfcodec.studio.browser import paint_count, wait_for_paint_after

    requests_before = page.evaluate("window.studio.previews.editor.requestCount")
    count = paint_count(page)
    # 60 input events in one task, as a fast drag produces them: at most one decode in flight, the newest sent next.
    page.evaluate("""() => { const el = document.getElementById('z0');
        for (let i = 0; i < 60; i++) { el.value = String(-3 + i * 0.1);
            el.dispatchEvent(new Event('input', {bubbles: true})); } }""")
    wait_for_paint_after(page, count)
    sent = page.evaluate("window.studio.previews.editor.requestCount") - requests_before
    assert sent <= 3, sent  # the first value, then only the newest
    last = float(page.evaluate("document.getElementById('z0').value"))
    assert page.evaluate("window.studio.previews.editor.shownState.z[0]") == pytest.approx(last)
    assert painted_error(page, studio_env["catalogue"], "editor") < MAX_DELTA_E_ITP


def test_light_drag_moves_the_highlight(page: Any, studio_env: dict[str, Any]) -> None:
    from brdfcodec.studio.browser import canvas_pixels, paint_count, wait_for_paint_after

    before = canvas_pixels(page, "editor-canvas")
    box = page.locator("#editor-canvas").bounding_box()
    count = paint_count(page)
    page.mouse.move(box["x"] + box["width"] * 0.5, box["y"] + box["height"] * 0.5)
    page.mouse.down()
    page.mouse.move(box["x"] + box["width"] * 0.8, box["y"] + box["height"] * 0.6, steps=5)
    page.mouse.up()
    wait_for_paint_after(page, count)
    light = page.evaluate("window.studio.previews.editor.light")
    assert light[0] > 0.3 and light[1] < 0  # now from the right, below
    assert np.abs(canvas_pixels(page, "editor-canvas").astype(int) - before.astype(int)).mean() > 2.0
    assert painted_error(page, studio_env["catalogue"], "editor") < MAX_DELTA_E_ITP


def test_undo_and_reset(page: Any) -> None:
    from brdfcodec.studio.browser import paint_count, set_slider, wait_for_paint_after

    original = page.evaluate("window.studio.editor.state.z")
    count = paint_count(page)
    set_slider(page, "z6", 2.0)
    page.evaluate("document.getElementById('z6').dispatchEvent(new Event('change', {bubbles: true}))")
    wait_for_paint_after(page, count)
    assert page.evaluate("window.studio.editor.state.z[6]") == pytest.approx(2.0)
    count = paint_count(page)
    page.click("#undo")
    wait_for_paint_after(page, count)
    assert np.allclose(page.evaluate("window.studio.editor.state.z"), original)
    count = paint_count(page)
    page.click("#sample")
    wait_for_paint_after(page, count)
    assert not np.allclose(page.evaluate("window.studio.editor.state.z"), original)
    count = paint_count(page)
    page.click("#reset")
    wait_for_paint_after(page, count)
    assert np.allclose(page.evaluate("window.studio.previews.editor.shownState.z"), original)


def test_two_tabs_keep_their_own_state(studio_env: dict[str, Any]) -> None:
    from brdfcodec.studio.browser import open_studio, paint_count, set_slider, wait_for_paint_after

    first = open_studio(studio_env["context"], studio_env["url"])
    second = open_studio(studio_env["context"], studio_env["url"])
    try:
        counts = (paint_count(first), paint_count(second))
        second.select_option("#material", "chrome")
        set_slider(first, "z3", 2.5)
        set_slider(second, "z3", -2.5)
        wait_for_paint_after(first, counts[0])
        wait_for_paint_after(second, counts[1])
        a = first.evaluate("window.studio.previews.editor.shownState.z")
        b = second.evaluate("window.studio.previews.editor.shownState.z")
        assert a[3] == pytest.approx(2.5) and b[3] == pytest.approx(-2.5)
        chrome = studio_env["catalogue"].record("chrome").mu
        assert np.allclose(np.delete(b, 3), np.delete(chrome, 3), atol=1e-6)
        for tab in (first, second):
            assert painted_error(tab, studio_env["catalogue"], "editor") < MAX_DELTA_E_ITP
    finally:
        first.close()
        second.close()


def test_saving_asks_before_replacing(page: Any, studio_env: dict[str, Any]) -> None:
    from brdfcodec.format.bvae import read_bvae

    save_dir: Path = studio_env["save_dir"]
    page.fill("#save-file", "tab-edit.bvae")
    page.fill("#save-name", "tab-edit")
    page.click("#save-box button[data-suffix='.bvae']")
    page.wait_for_function("document.getElementById('save-status').textContent.startsWith('wrote')")
    target = save_dir / "tab-edit.bvae"
    saved = read_bvae(target).records[0]
    assert saved.name == "tab-edit" and saved.meta["edit"]["op"] == "studio"
    before = target.read_bytes()

    answers: list[str] = []

    def refuse(dialog: Any) -> None:
        answers.append(dialog.message)
        dialog.dismiss()

    page.on("dialog", refuse)
    page.evaluate("document.getElementById('save-status').textContent = ''")
    page.click("#save-box button[data-suffix='.bvae']")
    page.wait_for_function("document.getElementById('save-status').textContent.startsWith('not saved')")
    assert answers and "already exists" in answers[0]
    assert target.read_bytes() == before
    page.remove_listener("dialog", refuse)
    page.on("dialog", lambda dialog: dialog.accept())
    page.evaluate("document.getElementById('save-status').textContent = ''")
    page.click("#save-box button[data-suffix='.png']")
    page.wait_for_function("document.getElementById('save-status').textContent.startsWith('wrote')")
    page.evaluate("document.getElementById('save-status').textContent = ''")
    page.click("#save-box button[data-suffix='.png']")
    page.wait_for_function("document.getElementById('save-status').textContent.startsWith('wrote')")
    assert (save_dir / "tab-edit.png").is_file()


def test_explorer_cursor_decodes_the_inverse_transform(page: Any, studio_env: dict[str, Any]) -> None:
    from brdfcodec.studio.browser import canvas_pixels, paint_count, wait_for_paint_after
    from brdfcodec.studio.manifold import cached_manifold, latent_at

    page.wait_for_function("window.studio.explorer.map !== null", timeout=600_000)  # first UMAP fit: seconds
    page.wait_for_function("window.studio.previews.explorer.paintCount >= 1")
    before = canvas_pixels(page, "explorer-canvas")
    box = page.locator("#map").bounding_box()
    count = paint_count(page, "explorer")
    page.mouse.move(box["x"] + box["width"] * 0.5, box["y"] + box["height"] * 0.5)
    page.mouse.down()
    page.mouse.move(box["x"] + box["width"] * 0.2, box["y"] + box["height"] * 0.3, steps=8)
    page.mouse.up()
    wait_for_paint_after(page, count, "explorer")
    x, y = page.evaluate("window.studio.explorer.cursor")
    catalogue = studio_env["catalogue"]
    manifold = cached_manifold(catalogue.codes(), catalogue.ids(), catalogue.decoder.reference.sha256,
                               folder=studio_env["cache"])
    shown = page.evaluate("window.studio.previews.explorer.shownState.z")
    assert np.allclose(shown, latent_at(manifold, x, y), atol=2e-4)  # the grid is sent rounded to 1e-5
    assert np.abs(canvas_pixels(page, "explorer-canvas").astype(int) - before.astype(int)).mean() > 1.0
    assert painted_error(page, catalogue, "explorer") < MAX_DELTA_E_ITP

    # Hovering a material shows its thumbnail; the point goes to the editor on request.
    point = page.evaluate("window.studio.explorer.map.points[0]")
    cx, cy = page.evaluate(f"window.studio.explorer.toCanvas({point['x']}, {point['y']})")
    page.mouse.move(box["x"] + cx * box["width"] / 440, box["y"] + cy * box["height"] / 440)
    page.wait_for_function("!document.getElementById('map-tip').hidden")
    assert page.text_content("#map-tip-name") == point["id"]
    count = paint_count(page)
    page.click("#to-editor")
    wait_for_paint_after(page, count)
    assert np.allclose(page.evaluate("window.studio.editor.state.z"), shown, atol=1e-6)


def test_sky_lighting_is_painted_from_the_server(page: Any) -> None:
    from brdfcodec.studio.browser import canvas_pixels, paint_count, wait_for_paint_after

    before = canvas_pixels(page, "editor-canvas")
    count = paint_count(page)
    page.select_option("#lighting", "sky")
    wait_for_paint_after(page, count)
    after = canvas_pixels(page, "editor-canvas")
    assert np.abs(after.astype(int) - before.astype(int)).mean() > 2.0
    assert after.max() > 0
