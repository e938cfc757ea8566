"""``python -m lagsplat.synth.continuum_robot``: see :func:`lagsplat.synth.continuum_robot.cli.main`."""

import sys

from lagsplat.synth.continuum_robot.cli import main

sys.exit(main())
