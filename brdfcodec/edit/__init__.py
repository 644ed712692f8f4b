"""Editing in the latent: traversal, interpolation, grafting, the named parameters, plausibility."""
