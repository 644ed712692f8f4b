"""Image-space error between renders: ΔE ITP, ΔE 2000 (colour-science) and PSNR.

Both renders are put on a display scale first: one exposure, chosen so that
the reference's 99th-percentile luminance is 1, and 1.0 = 100 cd/m²
(values above 10, i.e. 1000 cd/m², are clipped). ΔE ITP (ITU-R BT.2124)
converts linear sRGB to BT.2020, then to ICtCp with the PQ curve at absolute
luminance; ΔE 2000 uses CIELAB with the D65 white at 1.0; PSNR uses the
sRGB-encoded images clipped to [0, 1]. Statistics are over the pixels that
either render covers.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import numpy.typing as npt

from brdfcodec.render.images import auto_exposure

__all__ = ["ImageComparison", "compare_images", "image_error"]

_WHITE_NITS = 100.0
_PEAK = 10.0


@dataclass(frozen=True)
class ImageComparison:
    """Image-space comparison of a test render with a reference render (a result, not an exception).

    Attributes
    ----------
    delta_e_itp_mean, delta_e_itp_p95 : float
        ΔE ITP, mean and 95th percentile over covered pixels (1 ≈ just noticeable).
    delta_e_2000_mean, delta_e_2000_p95 : float
        CIEDE2000, mean and 95th percentile.
    psnr_db : float
        PSNR of the sRGB-encoded images, dB (inf when identical).
    exposure : float
        The display scale used.
    """

    delta_e_itp_mean: float
    delta_e_itp_p95: float
    delta_e_2000_mean: float
    delta_e_2000_p95: float
    psnr_db: float
    exposure: float

    def as_dict(self) -> dict[str, float]:
        """The fields as a dictionary."""
        return asdict(self)


def compare_images(reference: npt.ArrayLike, test: npt.ArrayLike, *, exposure: float | None = None) -> ImageComparison:
    """ΔE ITP, ΔE 2000 and PSNR between two linear-RGB renders of equal shape (H, W, 3)."""
    from brdfcodec.render.images import colour_module

    colour = colour_module()

    ref = np.asarray(reference, dtype=np.float64)
    est = np.asarray(test, dtype=np.float64)
    if ref.shape != est.shape or ref.ndim != 3 or ref.shape[2] != 3:
        raise ValueError(f"renders must have the same (H, W, 3) shape, got {ref.shape} and {est.shape}")
    if not (np.isfinite(ref).all() and np.isfinite(est).all()):
        raise ValueError("renders must be finite")
    scale = auto_exposure(ref) if exposure is None else exposure
    covered = (ref.sum(-1) > 0) | (est.sum(-1) > 0)
    if not covered.any():
        return ImageComparison(0.0, 0.0, 0.0, 0.0, float("inf"), scale)
    a = np.clip(ref[covered] * scale, 0, _PEAK)
    b = np.clip(est[covered] * scale, 0, _PEAK)

    def itp(rgb: np.ndarray) -> np.ndarray:
        bt2020 = colour.RGB_to_RGB(rgb, "sRGB", "ITU-R BT.2020", apply_cctf_decoding=False, apply_cctf_encoding=False)
        return colour.RGB_to_ICtCp(np.clip(bt2020, 0, None) * (_WHITE_NITS / 10000.0), L_p=10000)

    def lab(rgb: np.ndarray) -> np.ndarray:
        return colour.XYZ_to_Lab(colour.sRGB_to_XYZ(rgb, apply_cctf_decoding=False))

    d_itp = np.asarray(colour.delta_E(itp(a), itp(b), method="ITP"))
    d_2000 = np.asarray(colour.delta_E(lab(a), lab(b), method="CIE 2000"))
    enc_a = colour.cctf_encoding(np.clip(a, 0, 1), function="sRGB")
    enc_b = colour.cctf_encoding(np.clip(b, 0, 1), function="sRGB")
    mse = float(np.mean((np.asarray(enc_a) - np.asarray(enc_b)) ** 2))
    psnr = float("inf") if mse == 0 else float(10 * np.log10(1.0 / mse))
    return ImageComparison(
        delta_e_itp_mean=float(d_itp.mean()),
        delta_e_itp_p95=float(np.percentile(d_itp, 95)),
        delta_e_2000_mean=float(d_2000.mean()),
        delta_e_2000_p95=float(np.percentile(d_2000, 95)),
        psnr_db=psnr,
        exposure=scale,
    )


#: Former name of :func:`compare_images`.
image_error = compare_images
