"""``python -m lagsplat <stage> ...``: see :mod:`lagsplat.cli`."""

import sys

from lagsplat.cli import main

sys.exit(main())
