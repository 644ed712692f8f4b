"""The codec: MERL tables to ``.bvae`` bytes and back (needs torch).

Model resolution and source preparation, the decoder, the encoder with its
options and rate control, the file-backed library, the one-shot functions,
and writing decoded materials as RGL ``.bsdf`` files. Everything public is
re-exported here.
"""

from brdfcodec.codec.api import *  # noqa: F403
from brdfcodec.codec.api import __all__ as _api_names
from brdfcodec.codec.rgl_export import export_rgl

__all__ = [*_api_names, "export_rgl"]
