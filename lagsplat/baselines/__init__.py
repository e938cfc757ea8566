"""Baselines without the Lagrangian prior, scored on the same chart and protocol (paper §4.3, Table 3).

* :mod:`lagsplat.baselines.neural_ode`: a latent neural ODE, an unconstrained vector field for
  ``(q, qdot)`` on the frozen LaGSplat chart, trained like Stage 2.
* :mod:`lagsplat.baselines.gp2d` (with :mod:`~lagsplat.baselines.gp2d_field` and :mod:`~lagsplat.baselines.gp2d_forecast`):
  GP-2D, a re-implementation of GaussianPrediction's motion-prediction structure in the image plane (a deformation
  field, key points, a free graph-network forecaster), not the original code; :mod:`lagsplat.baselines.gp_frames`
  imports frames predicted by the original.
* :mod:`lagsplat.baselines.extrapolation`: the protocol every model is scored by (train on the first
  part, predict the rest and 1000 s past it; frequency, dissipation, amplitude left, PSNR).
"""

from __future__ import annotations

from lagsplat.lazy import lazy_exports

__all__ = ["LatentNeuralODE", "ode_rollout", "train_neural_ode"]

# imported on first use: the configuration schema imports the baselines' settings from their modules, and every
# stage would otherwise pay for the ODE solvers' SciPy
__getattr__, __dir__ = lazy_exports(__name__, dict.fromkeys(__all__, "neural_ode"))
