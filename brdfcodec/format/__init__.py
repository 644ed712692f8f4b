"""Records ↔ bytes: the ``.bvae`` file format (``spec/bvae-format.md``).

Every record kind (latent, graft, layered), material names and the strict
JSON header. It sits on :mod:`brdfcodec.layers` (the bytes of the enhancement
layers) and never imports torch, the networks or the codec.
"""
