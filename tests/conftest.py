"""Shared test set-up.

Importing lagsplat first sets ``GOMP_SPINCOUNT`` before torch starts
its OpenMP pool (see lagsplat/__init__.py): torch's spinning threads otherwise
starve the numba rasterizer's workers on a 2-core machine.
"""

import lagsplat  # noqa: F401  (must precede any torch import)
import pytest


@pytest.fixture(scope="module")
def one_torch_thread():
    """Run a module's tests with one torch thread, restoring the previous count afterwards.

    For modules working on tiny tensors: one thread avoids OpenMP hand-offs and
    is much faster (10-40x seen) than two on a loaded 2-core machine. Opt in
    with ``pytestmark = pytest.mark.usefixtures("one_torch_thread")``.
    """
    import torch

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)
