"""Image output for renders: exposure, sRGB encoding (colour-science), PNG (Pillow) and EXR, labelled sheets."""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from brdfcodec.io.atomic import atomic_output

__all__ = ["auto_exposure", "compose_sheet", "encode_srgb", "write_image", "write_png"]

_LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def colour_module() -> Any:
    """colour-science, imported without its notice about optional SciPy features (none are used here)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*SciPy.*")
        import colour
    return colour


def auto_exposure(image: npt.ArrayLike, *, percentile: float = 99.0) -> float:
    """Scale that maps the given percentile of the non-zero luminance to 1 (1.0 if the image is black)."""
    lum = np.asarray(image, dtype=np.float64) @ _LUMINANCE
    positive = lum[lum > 0]
    if positive.size == 0:
        return 1.0
    level = float(np.percentile(positive, percentile))
    return 1.0 / level if level > 0 and np.isfinite(level) else 1.0


def encode_srgb(linear: npt.ArrayLike, *, exposure: float = 1.0) -> npt.NDArray[np.uint8]:
    """Linear RGB × exposure, clipped to [0, 1], sRGB-encoded (colour-science), as 8-bit."""
    colour = colour_module()
    clipped = np.clip(np.nan_to_num(np.asarray(linear, dtype=np.float64) * exposure), 0.0, 1.0)
    encoded = colour.cctf_encoding(clipped, function="sRGB")
    return np.round(np.asarray(encoded) * 255.0).astype(np.uint8)


def write_png(path: str | os.PathLike[str], pixels: npt.ArrayLike, *, overwrite: bool = False) -> None:
    """Write 8-bit RGB pixels (H, W, 3) as PNG, atomically."""
    from PIL import Image

    array = np.asarray(pixels)
    if array.dtype != np.uint8 or array.ndim != 3 or array.shape[2] != 3:
        raise ValueError(f"expected uint8 (H, W, 3) pixels, got {array.dtype} {array.shape}")
    with atomic_output(path, overwrite=overwrite) as tmp:
        Image.fromarray(array, mode="RGB").save(tmp, format="PNG")


def write_image(
    path: str | os.PathLike[str], linear: npt.ArrayLike, *, exposure: float | None = None, overwrite: bool = False
) -> float:
    """Write a linear render as ``.exr`` (unchanged, float32) or ``.png`` (exposed, sRGB); returns the exposure."""
    suffix = os.fspath(path).lower().rsplit(".", 1)[-1]
    image = np.asarray(linear, dtype=np.float32)
    scale = auto_exposure(image) if exposure is None else exposure
    if suffix == "exr":
        from brdfcodec.io.exr import write_exr_rgb

        write_exr_rgb(path, image, overwrite=overwrite)
    elif suffix == "png":
        write_png(path, encode_srgb(image, exposure=scale), overwrite=overwrite)
    else:
        raise ValueError(f"{path}: unknown image type .{suffix}; use .png or .exr")
    return scale


_ASCII = str.maketrans({"σ": "sd", "→": "->", "−": "-", "±": "+/-", "°": " deg", "²": "^2"})


def _ascii(text: str) -> str:
    """Pillow's built-in font has ASCII glyphs only."""
    return text.translate(_ASCII).encode("ascii", "replace").decode("ascii")


def compose_sheet(
    tiles: Sequence[Sequence[npt.NDArray[np.uint8]]],
    *,
    row_labels: Sequence[str],
    column_labels: Sequence[str],
    title: str = "",
    label_width: int = 260,
    header_height: int = 40,
) -> npt.NDArray[np.uint8]:
    """Grid of equally sized 8-bit tiles with row and column labels (Pillow's default font)."""
    from PIL import Image, ImageDraw

    rows, cols = len(tiles), len(tiles[0])
    tile_h, tile_w = tiles[0][0].shape[:2]
    sheet = Image.new("RGB", (label_width + cols * tile_w, header_height + rows * tile_h), (24, 24, 24))
    draw = ImageDraw.Draw(sheet)
    if title:
        draw.text((6, 4), _ascii(title), fill=(235, 235, 235))
    for j, label in enumerate(column_labels):
        text = _ascii(label)
        draw.text((label_width + j * tile_w + tile_w // 2 - 3 * len(text), header_height - 16), text,
                  fill=(200, 200, 200))
    for i, row in enumerate(tiles):
        y = header_height + i * tile_h
        draw.text((6, y + tile_h // 2 - 6), _ascii(row_labels[i]), fill=(220, 220, 220))
        for j, tile in enumerate(row):
            sheet.paste(Image.fromarray(tile, mode="RGB"), (label_width + j * tile_w, y))
    return np.asarray(sheet)
