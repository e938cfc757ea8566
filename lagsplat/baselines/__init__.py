"""Baselines without the Lagrangian prior, scored on the same chart and protocol (paper §4.3, Table 3).

* :mod:`lagsplat.baselines.neural_ode`: a latent neural ODE, an unconstrained vector field for
  ``(q, qdot)`` on the frozen LaGSplat chart, trained like Stage 2.
* :mod:`lagsplat.baselines.extrapolation`: the protocol every model is scored by (train on the first
  part, predict the rest and 1000 s past it; frequency, dissipation, amplitude left, PSNR).
"""

from lagsplat.baselines.neural_ode import LatentNeuralODE, ode_rollout, train_neural_ode

__all__ = ["LatentNeuralODE", "ode_rollout", "train_neural_ode"]
