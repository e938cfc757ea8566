"""Shared test set-up.

Importing lagsplat first sets ``OMP_WAIT_POLICY=PASSIVE`` before torch starts
its OpenMP pool (see lagsplat/__init__.py): torch's spinning threads otherwise
starve the numba rasterizer's workers on a 2-core machine.
"""

import lagsplat  # noqa: F401  (must precede any torch import)
