"""``python -m bench``: the same entry point as the ``bench`` console script."""

import sys

from bench.cli import console_main

sys.exit(console_main())
