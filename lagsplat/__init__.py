"""lagsplat: latent dissipative Lagrangians rendered by conditioned Gaussian splats.

Turns a monocular video of a mechanical system into an identified physical
model: a Gaussian-splatting decoder conditioned on a latent state ``q`` and a
latent Lagrangian fitted to the encoded trajectory (see the paper, §3).
"""

import os as _os

# Training alternates torch's OpenMP kernels with the numba rasterizer's worker
# threads. OpenMP's default "active" wait makes idle torch threads spin on the
# cores the numba workers need; passive waiting was measured 2-4x faster per
# Stage-1 step on 2 cores (benchmarks/rasterizer.py). Must be set before torch
# starts its thread pool, hence here; an explicit user setting wins.
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

__version__ = "0.1.0"
