"""Files ↔ tables: MERL ``.binary``, RGL ``.bsdf``, EXR, and the file plumbing every writer shares.

The lowest layer of the package: it reads and writes measured-BRDF files and
knows nothing of the network, the latent or the ``.bvae`` format. No torch.
"""
