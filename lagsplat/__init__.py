"""lagsplat: latent dissipative Lagrangians rendered by conditioned Gaussian splats.

Turns a monocular video of a mechanical system into an identified physical
model: a Gaussian-splatting decoder conditioned on a latent state ``q`` and a
latent Lagrangian fitted to the encoded trajectory (see the paper, §3).
"""

__version__ = "0.1.0"
