"""``python -m cobus``: the same command line as ``cobus``."""

import sys

from cobus.cli import main

sys.exit(main())
