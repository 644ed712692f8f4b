"""Slim the wheels a device run carries, so that they fit the device tool's 64 MiB beside the checkout.

The device machine has no network: Mitsuba, Dr.Jit, colour-science and zstandard travel as cp312 wheels
(``benchmarks/device/README.md``). Mitsuba's wheel (62.6 MB) holds 13 variants, 100 plug-ins, headers and stubs;
the render stage needs one variant and the plug-ins of ``brdfcodec/data/scenes/spheres.xml``. colour-science's wheel
holds 78 MB of coverage pages and tests, zstandard's a second (cffi) backend. This tool rewrites each wheel without
what the run does not use and with a RECORD (sha256, size) of what it keeps, so that ``pip install --no-deps``
installs it as it would the original.

usage::

    python benchmarks/device/slim_wheels.py mitsuba SRC DST [--variant cuda_ad_rgb]
    python benchmarks/device/slim_wheels.py colour-science SRC DST
    python benchmarks/device/slim_wheels.py zstandard SRC DST

Check a slimmed Mitsuba here with ``--variant llvm_ad_rgb`` and the cp311 wheel: install it with ``pip install
--no-deps --target DIR`` and run the render stage with ``PYTHONPATH=DIR:$PWD`` (the README says how).
"""

from __future__ import annotations

import argparse
import base64
import hashlib
import re
import zipfile
from collections.abc import Callable
from pathlib import Path

#: Plug-ins the spheres scene names (integrator, sensor, sampler, film, emitters, shapes, BSDF), those the loader
#: adds on its own (the film's Gaussian filter, ``merge`` for the shapes, sRGB and uniform textures and spectra),
#: and a few small ones a scene edit may want. Each plug-in library holds every variant's code.
MITSUBA_PLUGINS = frozenset({
    "path", "perspective", "independent", "hdrfilm", "constant", "directional", "rectangle", "sphere", "diffuse",
    "gaussian", "box", "tent", "srgb", "uniform", "d65", "regular", "irregular", "bitmap", "direct", "blackbody",
    "merge",
})

_VARIANT_MODULE = re.compile(r"(scalar|llvm_ad|cuda_ad)_[a-z_]+(?=\.cpython)")


def rewrite_wheel(source: Path, target: Path, keep: Callable[[str], bool]) -> tuple[int, int]:
    """Write ``target``: the members of wheel ``source`` that ``keep`` accepts and a new RECORD.

    Returns
    -------
    tuple of int
        Members kept and dropped.

    Raises
    ------
    ValueError
        ``source`` holds no ``.dist-info/RECORD`` (not a wheel), or ``target`` is ``source``.
    """
    if target.resolve() == source.resolve():
        raise ValueError(f"{target}: the slimmed wheel would overwrite its source")
    kept = dropped = 0
    with zipfile.ZipFile(source) as wheel:
        record = next((name for name in wheel.namelist() if name.endswith(".dist-info/RECORD")), None)
        if record is None:
            raise ValueError(f"{source}: not a wheel (no .dist-info/RECORD)")
        lines = []
        partial = target.with_name(target.name + ".part")  # renamed to target once whole
        try:
            with zipfile.ZipFile(partial, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as out:
                for info in wheel.infolist():
                    if info.filename == record:
                        continue
                    if not keep(info.filename):
                        dropped += 1
                        continue
                    data = wheel.read(info)
                    member = zipfile.ZipInfo(info.filename, date_time=info.date_time)
                    member.external_attr = info.external_attr
                    out.writestr(member, data, compress_type=zipfile.ZIP_DEFLATED, compresslevel=9)
                    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
                    lines.append(f"{info.filename},sha256={digest},{len(data)}")
                    kept += 1
                lines.append(f"{record},,")
                member = zipfile.ZipInfo(record, date_time=(2020, 1, 1, 0, 0, 0))
                member.external_attr = 0o644 << 16
                out.writestr(member, "\n".join(lines) + "\n", compress_type=zipfile.ZIP_DEFLATED, compresslevel=9)
        except BaseException:
            partial.unlink(missing_ok=True)
            raise
    partial.replace(target)
    return kept, dropped


def keep_mitsuba(variant: str) -> Callable[[str], bool]:
    """Mitsuba's members that a render of the spheres scene in ``variant`` needs (libembree3 too: libmitsuba and
    every plug-in link it)."""
    def keep(name: str) -> bool:
        base = name.rsplit("/", 1)[-1]
        if name.startswith(("share/", "mitsuba/include/", "mitsuba/cmake/", "mitsuba/pkgconfig/",
                            "mitsuba/mitsuba_stubs/", "mitsuba/python/test/", "mitsuba/data/sunsky/")):
            return False
        if name in ("mitsuba/mitsuba", "mitsuba/data/srgb.coeff") or name.endswith(".pyi"):
            return False  # the command-line renderer; the spectral variants' upsampling table; type stubs
        module = _VARIANT_MODULE.match(base)
        if module and name.count("/") == 1:
            return module.group(0) == variant
        if base == "libIlmImfUtil-mitsuba.so":
            return False
        if name.startswith("mitsuba/plugins/"):
            return base.removesuffix(".so") in MITSUBA_PLUGINS
        return True
    return keep


def keep_colour_science(name: str) -> bool:
    """colour-science's members but its coverage pages, tests and examples."""
    return not ("/htmlcov/" in name or "/tests/" in name or name.startswith("colour/examples/"))


def keep_zstandard(name: str) -> bool:
    """zstandard's members but its cffi backend (the C backend is the one imported)."""
    return not (name.startswith("zstandard/_cffi.") or name == "zstandard/backend_cffi.py")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("package", choices=("mitsuba", "colour-science", "zstandard"))
    parser.add_argument("source", type=Path)
    parser.add_argument("target", type=Path)
    parser.add_argument("--variant", default="cuda_ad_rgb", help="the Mitsuba variant kept (default cuda_ad_rgb)")
    args = parser.parse_args()
    if not args.source.is_file():
        parser.error(f"{args.source}: no such file")
    keep = {"mitsuba": keep_mitsuba(args.variant), "colour-science": keep_colour_science,
            "zstandard": keep_zstandard}[args.package]
    try:
        kept, dropped = rewrite_wheel(args.source, args.target, keep)
    except (ValueError, zipfile.BadZipFile) as error:
        parser.error(str(error))
    print(f"{args.target}: {kept} members kept, {dropped} dropped, {args.target.stat().st_size:,} bytes")


if __name__ == "__main__":
    main()
