"""The codec: MERL tables to ``.bvae`` bytes and back (needs torch).

Two inverse functions on bytes, the shape codec libraries have::

    data = encode(brdfs)            # MerlBRDF objects or MERL file paths -> bytes of a .bvae file
    library = decode(data)          # bytes -> MaterialLibrary (name -> DecodedMaterial, decoded lazily)

and file helpers on top: :func:`compress` writes ``encode(...)`` atomically,
:func:`decompress` reads one material's table from a file. ``bvae compress``
calls :func:`encode_records`, the loop underneath :func:`encode`.

:class:`BrdfEncoder` and :class:`BrdfDecoder` hold a loaded network and its
device and are meant to be reused; they are the only code that runs the
networks in batches (training evaluation, export, the report and the named
parameters use them too, through :meth:`BrdfDecoder.from_network` for a
network in memory). :class:`MaterialLibrary` opens a ``.bvae`` file (or
bytes) and decodes a material only when it is first used, so a scene that
uses 3 materials of a library of 100 decodes 3.

Decoded tables follow ``spec/bvae-format.md`` §6: stored MERL units
(:func:`brdfcodec.representation.reflectance_from_stored` gives 1/sr),
float32, and entries whose bin lies below the horizon set to ``-1``
(unmeasured) unless asked otherwise.

The package's parts, lowest first: :mod:`~brdfcodec.codec.prepare` (model
resolution, source clamping), :mod:`~brdfcodec.codec.projection`,
:mod:`~brdfcodec.codec.decoder`, :mod:`~brdfcodec.codec.encoder` with its
options (:mod:`~brdfcodec.codec.encoding`), rate control
(:mod:`~brdfcodec.codec.rate`) and refinement (:mod:`~brdfcodec.codec.refine`),
:mod:`~brdfcodec.codec.library`, :mod:`~brdfcodec.codec.oneshot` and
:mod:`~brdfcodec.codec.rgl_export`.
"""

from brdfcodec.codec.decoder import BrdfDecoder
from brdfcodec.codec.encoder import BrdfEncoder, MaterialInput, measure
from brdfcodec.codec.library import DecodedMaterial, MaterialLibrary
from brdfcodec.codec.oneshot import compress, decode, decompress, encode, encode_records
from brdfcodec.codec.prepare import ClampWarning, MaskedEntries, prepare_source, resolve_model
from brdfcodec.codec.rgl_export import export_rgl

__all__ = [
    "BrdfDecoder",
    "BrdfEncoder",
    "ClampWarning",
    "DecodedMaterial",
    "MaskedEntries",
    "MaterialInput",
    "MaterialLibrary",
    "compress",
    "decode",
    "decompress",
    "encode",
    "encode_records",
    "export_rgl",
    "measure",
    "prepare_source",
    "resolve_model",
]
