"""``python -m nerf_bundle``: see :mod:`nerf_bundle.cli`."""
import sys

from .cli import main

sys.exit(main())
