"""The identified dynamics as a standalone module: ``dynamics.py`` (NumPy) and its float64 ``weights.npz``.

The weights are those the compiled rollout reads (:func:`lagsplat.dynamics.fast_export.export_model`, a
:class:`~lagsplat.dynamics.fast_export.FastModel`), one array per field; ``dynamics.py`` is a copy of
:mod:`lagsplat.export.standalone_dynamics`, which imports nothing but NumPy.
"""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import numpy as np

from lagsplat.dynamics.fast_export import FastModel, export_model, unsupported_reason
from lagsplat.export import standalone_dynamics
from lagsplat.io.atomic import atomic_write, write_npz
from lagsplat.models.lagrangian import Lagrangian

__all__ = ["DYNAMICS_FILE", "WEIGHTS_FILE", "check_exportable", "weight_arrays", "write_dynamics"]

DYNAMICS_FILE = "dynamics.py"
WEIGHTS_FILE = standalone_dynamics.WEIGHTS


def check_exportable(model: object) -> None:
    """Raise when the standalone module cannot represent ``model``.

    Supported: a :class:`Lagrangian` with ``mass`` ``"scalar"``, ``"constant"`` or ``"learned"``, a convex or
    invex potential and any number of inputs: the models of the compiled rollout path
    (:func:`~lagsplat.dynamics.fast_export.unsupported_reason`).

    Raises:
        ValueError: naming the reason, e.g. the decoder-induced inertia (``mass="decoder"``).
    """
    why = unsupported_reason(model)
    if why is not None:
        raise ValueError(f"this model cannot be exported: {why}")


def weight_arrays(fm: FastModel) -> dict[str, np.ndarray]:
    """Every field of ``fm`` as an array (float64 weights, int64 sizes and indices, a string ``mass_kind``)."""
    out = {}
    for f in dataclasses.fields(fm):
        v = getattr(fm, f.name)
        if isinstance(v, np.ndarray):
            out[f.name] = v.astype(np.int64 if v.dtype.kind in "iu" else np.float64)
        elif isinstance(v, str):
            out[f.name] = np.array(v)
        elif isinstance(v, int):
            out[f.name] = np.array(v, np.int64)
        else:
            out[f.name] = np.array(float(v))
    return out


def write_dynamics(model: Lagrangian, out_dir: str | Path) -> dict[str, Path]:
    """Write ``dynamics.py`` and ``weights.npz`` into ``out_dir``, atomically.

    ``dynamics.rhs(t, [q, qdot], u=None)`` is the Euler-Lagrange right-hand side of paper Eq. 7 (inputs through
    the map of Eq. 6) for ``scipy.integrate.solve_ivp``; ``dynamics.rollout_verlet`` the project's scheme (Eq. 8).

    Args:
        model: the Stage-2 Lagrangian (eval mode).
        out_dir: the export folder.

    Returns:
        ``{"dynamics": path, "weights": path}``.

    Raises:
        ValueError: for a model the standalone module cannot represent (:func:`check_exportable`).
    """
    check_exportable(model)
    out = Path(out_dir)
    weights = write_npz(out / WEIGHTS_FILE, compressed=False, **weight_arrays(export_model(model)))
    with atomic_write(out / DYNAMICS_FILE) as tmp:
        shutil.copyfile(standalone_dynamics.__file__, tmp)
    return {"dynamics": out / DYNAMICS_FILE, "weights": weights}
