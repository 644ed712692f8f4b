"""Screenshots of the studio's two interfaces for the docs: ``python -m brdfcodec.studio.screenshots -o docs``.

Starts the studio on the shipped example library (NBRDF proxy of MERL) in a
thread, drives Debian's chromium (Playwright, system executable), makes an
edit in the editor (green-acrylic with z2 lowered, interpolated a quarter of
the way towards gold-metallic-paint with z4 and z5 kept) and moves the map
cursor in the explorer, then writes ``studio-editor.png`` and
``studio-explorer.png``. Existing files are replaced only with ``--force``.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from brdfcodec.io.atomic import check_output_path

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    """Write the two screenshots into the output folder."""
    parser = argparse.ArgumentParser(prog="python -m brdfcodec.studio.screenshots", description=__doc__)
    parser.add_argument("-o", "--output", type=Path, default=Path("docs"), help="output folder (default docs)")
    parser.add_argument("--force", action="store_true", help="replace existing screenshots")
    args = parser.parse_args(argv)

    from brdfcodec.studio.browser import (
        chromium_browser,
        open_studio,
        paint_count,
        running_studio,
        set_slider,
        wait_for_paint_after,
    )
    from brdfcodec.studio.catalogue import Catalogue
    from brdfcodec.studio.server import StudioServer, create_app

    editor_png = check_output_path(args.output / "studio-editor.png", overwrite=args.force)
    explorer_png = check_output_path(args.output / "studio-explorer.png", overwrite=args.force)
    with tempfile.TemporaryDirectory() as saves:
        server = StudioServer(Catalogue(), save_dir=saves)
        with running_studio(create_app(server)) as url, chromium_browser() as context:
            page = open_studio(context, url)
            count = paint_count(page)
            page.select_option("#material", "green-acrylic")
            wait_for_paint_after(page, count)
            for box in ("#from-a-3", "#from-a-4"):
                page.check(box)
            count = paint_count(page)
            page.select_option("#material-b", "gold-metallic-paint")
            set_slider(page, "interp-t", 0.25)
            wait_for_paint_after(page, count)
            count = paint_count(page)
            set_slider(page, "z1", 0.8)
            wait_for_paint_after(page, count)
            page.wait_for_function("window.studio.explorer.map !== null", timeout=600_000)
            box = page.locator("#map").bounding_box()
            count = paint_count(page, "explorer")
            page.mouse.move(box["x"] + box["width"] * 0.5, box["y"] + box["height"] * 0.5)
            page.mouse.down()
            page.mouse.move(box["x"] + box["width"] * 0.42, box["y"] + box["height"] * 0.3, steps=6)
            page.mouse.up()
            wait_for_paint_after(page, count, "explorer")
            point = page.evaluate("window.studio.explorer.map.points.find(p => p.id === 'gold-metallic-paint')")
            cx, cy = page.evaluate(f"window.studio.explorer.toCanvas({point['x']}, {point['y']})")
            rect = page.evaluate("(() => { const r = document.getElementById('map').getBoundingClientRect(); "
                                 "return [r.left, r.top, r.width / 440]; })()")
            page.evaluate("([x, y]) => window.studio.explorer.hover({clientX: x, clientY: y})",
                          [rect[0] + cx * rect[2], rect[1] + cy * rect[2]])
            page.wait_for_function("!document.getElementById('map-tip').hidden", timeout=20_000)
            page.wait_for_function("document.getElementById('map-tip-img').naturalWidth > 0", timeout=60_000)
            page.locator("#editor").screenshot(path=str(editor_png))
            page.locator("#explorer").screenshot(path=str(explorer_png))
    print(f"wrote {editor_png} and {explorer_png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
