"""bvae studio on a layered record, in a real browser (issue 41, part 6): sliders edit the base, the layers stay.

Library: an analytic red plastic compressed into 16 KB (a basis and a detail
layer) beside a plain latent record. The editor's sliders move the layered
record's code; what the page paints must be the render of the edited record
*with* its layers (``spec/bvae-format.md`` §4.4, "Edits") and not of the
edited base alone, and resetting returns the original picture. Debian's
chromium driven by Playwright, as in ``tests/test_studio_browser.py``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from brdfcodec.studio.browser import browser_missing_reason

_REASON = browser_missing_reason()
pytestmark = [pytest.mark.skipif(_REASON is not None, reason=_REASON or ""), pytest.mark.slow]

#: Largest mean ΔE ITP between the painted preview and the library's render of the same record (as in
#: tests/test_studio_browser.py: 8-bit quantisation of the painted canvas).
MAX_DELTA_E_ITP = 0.1


@pytest.fixture(scope="module")
def studio_env(tmp_path_factory: pytest.TempPathFactory) -> Any:
    from brdfcodec.codec import compress
    from brdfcodec.datasets.analytic import ANALYTIC_PRESETS
    from brdfcodec.format.bvae import LatentRecord, read_bvae, write_bvae
    from brdfcodec.studio.browser import chromium_browser, running_studio
    from brdfcodec.studio.catalogue import Catalogue
    from brdfcodec.studio.server import StudioServer, create_app

    folder = tmp_path_factory.mktemp("layered-studio")
    single = folder / "rp16k.bvae"
    compress([ANALYTIC_PRESETS["red-plastic"].to_merl()], single, names=["rp"], bytes=16384, measure_error=False)
    stored = read_bvae(single)
    library = folder / "layered.bvae"
    plain = LatentRecord("plain", np.zeros(8, np.float32), np.ones(8, np.float32))
    write_bvae(library, [stored.records[0], plain], stored.header.decoder)
    catalogue = Catalogue([library])
    server = StudioServer(catalogue, save_dir=folder, manifold_cache=folder / "umap-cache")
    with running_studio(create_app(server)) as url, chromium_browser() as context:
        yield {"url": url, "context": context, "catalogue": catalogue}


@pytest.fixture
def page(studio_env: dict[str, Any]) -> Any:
    from brdfcodec.studio.browser import open_studio

    page = open_studio(studio_env["context"], studio_env["url"])
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    yield page
    page.close()
    assert not errors, errors


def painted_against(page: Any, record: Any, catalogue: Any) -> float:
    """Mean ΔE ITP between the editor's canvas and render_sphere of ``record`` (the page's light and exposure)."""
    from brdfcodec.codec import DecodedMaterial
    from brdfcodec.render.image_metrics import image_error
    from brdfcodec.render.preview import render_sphere
    from brdfcodec.studio.browser import canvas_pixels, srgb_to_linear

    light = page.evaluate("window.studio.previews.editor.light")
    exposure = page.evaluate("(p => p.exposure * p.exposureScale)(window.studio.previews.editor)")
    linear = render_sphere(DecodedMaterial(record, catalogue.decoder), size=256, light=light)
    painted = canvas_pixels(page, "editor-canvas")
    return image_error(np.clip(linear * exposure, 0.0, 1.0), srgb_to_linear(painted), exposure=1.0).delta_e_itp_mean


def test_sliders_edit_a_layered_record_and_keep_its_layers(page: Any, studio_env: dict[str, Any]) -> None:
    from brdfcodec.edit.latent_edits import with_parameters
    from brdfcodec.format.bvae import LatentRecord
    from brdfcodec.studio.browser import canvas_pixels, paint_count, set_slider, wait_for_paint_after

    catalogue = studio_env["catalogue"]
    layered = catalogue.record("rp")
    assert page.evaluate("window.studio.editor.state.base") == "rp"
    assert painted_against(page, layered, catalogue) < MAX_DELTA_E_ITP
    original = canvas_pixels(page, "editor-canvas")

    count = paint_count(page)
    set_slider(page, "z3", float(layered.mu[3]) + 1.5)
    wait_for_paint_after(page, count)
    z = np.asarray(page.evaluate("window.studio.previews.editor.shownState.z"), dtype=np.float32)
    assert z[3] == pytest.approx(layered.mu[3] + 1.5, abs=0.01)
    edited = with_parameters(layered, z, name="e", edit={"op": "studio"})
    with_layers = painted_against(page, edited, catalogue)
    base_only = painted_against(page, LatentRecord("b", z, layered.sigma), catalogue)
    assert with_layers < MAX_DELTA_E_ITP
    assert base_only > 3 * with_layers  # the page shows the layers, not the edited base alone
    assert np.abs(canvas_pixels(page, "editor-canvas").astype(int) - original.astype(int)).mean() > 1.0

    count = paint_count(page)
    page.click("#reset")
    wait_for_paint_after(page, count)
    np.testing.assert_array_equal(page.evaluate("window.studio.editor.state.z"), layered.mu)
    np.testing.assert_array_equal(canvas_pixels(page, "editor-canvas"), original)  # undone: the same picture


def test_a_plain_record_beside_it_still_edits_without_layers(page: Any, studio_env: dict[str, Any]) -> None:
    from brdfcodec.format.bvae import LatentRecord
    from brdfcodec.studio.browser import paint_count, set_slider, wait_for_paint_after

    catalogue = studio_env["catalogue"]
    count = paint_count(page)
    page.select_option("#material", "plain")
    wait_for_paint_after(page, count)
    count = paint_count(page)
    set_slider(page, "z1", 1.0)
    wait_for_paint_after(page, count)
    z = np.asarray(page.evaluate("window.studio.previews.editor.shownState.z"), dtype=np.float32)
    assert painted_against(page, LatentRecord("p", z, np.ones(8, np.float32)), catalogue) < MAX_DELTA_E_ITP
