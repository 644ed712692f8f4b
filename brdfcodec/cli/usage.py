"""Usage errors of ``bvae`` sub-commands: arguments that parse but make no sense together (exit code 2)."""

from __future__ import annotations

__all__ = ["UsageError"]


class UsageError(ValueError):
    """The command line asks for something impossible (``--dim 9`` of 8, a library without ``--material``).

    ``bvae`` prints the message and exits with code 2, as for arguments
    ``argparse`` refuses; a ``ValueError`` subclass, so code calling the
    handlers directly needs no new case.
    """
