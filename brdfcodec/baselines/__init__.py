"""Classical baselines the β-VAE is measured against."""
