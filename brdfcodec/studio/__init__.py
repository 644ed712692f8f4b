"""``bvae studio``: the paper's interfaces in the browser, and the UMAP manifold figure.

* :mod:`brdfcodec.studio.catalogue` — the opened libraries: materials named by
  id only (the client never names a file), their latents and the model's
  parameter names.
* :mod:`brdfcodec.studio.manifold` — the UMAP embedding of a library's latents
  (umap-learn), cached per library and model, with its inverse transform
  tabulated on a grid for live dragging.
* :mod:`brdfcodec.studio.figure` — the paper's UMAP figure
  (``bvae render --umap-grid N``).
* :mod:`brdfcodec.studio.server` — the Starlette application (needs the
  ``studio`` extra: ``pip install "brdfcodec[studio]"``); the front-end in
  ``static/`` renders the preview in the browser from decoded kept slices.
* :mod:`brdfcodec.studio.browser` — driving the studio in Debian's chromium
  through Playwright (tests, benchmark); :mod:`brdfcodec.studio.screenshots`
  — the docs' screenshots (``python -m brdfcodec.studio.screenshots -o docs``).

Importing this package imports neither Starlette nor umap-learn.
"""

from __future__ import annotations

__all__ = ["StudioError"]


class StudioError(ValueError):
    """A request the studio refuses: a message for the client and an HTTP status (4xx)."""

    def __init__(self, message: str, status: int = 400) -> None:
        super().__init__(message)
        self.status = status
