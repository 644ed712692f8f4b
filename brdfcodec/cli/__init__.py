"""The ``bvae`` command line."""

from brdfcodec.cli.main import main

__all__ = ["main"]
