"""``python -m brdfcodec`` runs the ``bvae`` command line."""

import sys

from brdfcodec.cli import main

sys.exit(main())
