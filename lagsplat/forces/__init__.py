"""Forces at inference (paper §3.4, §4.5, Fig. 7): an applied force pulled back into the latent dynamics, and its checks.

* :mod:`lagsplat.forces.transport`: an image-plane force at a pixel pulled back as ``kappa J_bar(x)^T f``
  (:class:`ForceTransport`, the brushes :data:`BRUSHES`, :class:`Selection` of the material under a click),
  the edited dynamics a viewer drives (:class:`EditedDynamics`) and the energy factor ``kappa``
  (:func:`calibrate_kappa`).
* :mod:`lagsplat.forces.transport3d`: the same on the 3-D decoder, a pixel of any view casting a ray and a
  world-space force (:class:`ForceTransport3D`).
* :mod:`lagsplat.forces.checks`: what the transport's geometry predicts, measured on a trained model
  (background, linearity, kernel, lever arm; ``python -m lagsplat forces``).

Names are imported from their module on first use, so the configuration schema's
``from lagsplat.forces.checks import ForceCheckConfig`` does not load the 3-D transport.
"""

from __future__ import annotations

from lagsplat.lazy import lazy_exports

_EXPORTS = {
    "BRUSHES": "transport",
    "ChartKinematics": "transport",
    "EditedDynamics": "transport",
    "ForceTransport": "transport",
    "Selection": "transport",
    "brush_samples": "transport",
    "calibrate_kappa": "transport",
    "compositing_weights": "transport",
    "ForceTransport3D": "transport3d",
    "ForceCheckConfig": "checks",
    "lever_profile": "checks",
    "object_at_rest": "checks",
    "plot_force_checks": "checks",
    "public_result": "checks",
    "run_force_checks": "checks",
}

__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
