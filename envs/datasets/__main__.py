"""``python -m envs.datasets check SPEC``: see :mod:`envs.datasets.check`."""
import sys

from .check import main

sys.exit(main())
