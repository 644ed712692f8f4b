"""Version of the brdfcodec package."""

__version__ = "0.1.0"
