"""lagsplat: latent dissipative Lagrangians rendered by conditioned Gaussian splats.

Turns a monocular video of a mechanical system into an identified physical
model: a Gaussian-splatting decoder conditioned on a latent state ``q`` and a
latent Lagrangian fitted to the encoded trajectory (see the paper, §3).
"""

import os as _os

# Training alternates torch's OpenMP kernels with the numba rasteriser's own
# OpenMP pool (two runtimes, two pools on the same cores). An idle OpenMP
# thread spins before it sleeps: spinning for ever (OMP_WAIT_POLICY=ACTIVE)
# starves the other pool, never spinning (PASSIVE) makes each of the hundreds
# of small torch operations of a step wait for a sleeping thread to wake. A
# short spin (about tens of microseconds) keeps both: a Stage-1 step is faster
# with it than with PASSIVE or the runtime's default (benchmarks/stage1.py
# times a step; docs/experiments/code_comment_history.md). Must be set before
# torch starts its thread pool, hence here; an explicit user setting wins.
_os.environ.setdefault("GOMP_SPINCOUNT", "30000")

__version__ = "0.1.0"
