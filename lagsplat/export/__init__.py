"""Export of an identified model for use outside lagsplat (``python -m lagsplat export``; docs/export.md).

:func:`export_run` writes a run's ``export/`` folder: the dynamics as a NumPy module and its weights
(:mod:`~lagsplat.export.dynamics_files`, :mod:`~lagsplat.export.standalone_dynamics`), TorchScript terms
(:mod:`~lagsplat.export.torchscript`), ``model.json`` (:mod:`~lagsplat.export.card`), CSV tables
(:mod:`~lagsplat.export.tables`) and the decoder as 3DGS ``.ply`` files (:mod:`~lagsplat.export.splats`).
"""

from __future__ import annotations

from lagsplat.lazy import lazy_exports

__all__ = ["export_run"]

__getattr__, __dir__ = lazy_exports(__name__, {"export_run": "run"})
