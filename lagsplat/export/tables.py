"""The chart trajectory and a free rollout as CSV tables (a header row, comma-separated, time in seconds).

* ``trajectory.csv``: ``t, q_1..q_d, qdot_1..qdot_d[, u_1..u_n], split[, episode]``: the encoded chart
  trajectory, its velocity (:func:`chart_velocity`) and the frame's split (``train`` / ``held_out``);
* ``rollout.csv``: ``t, q_1..q_d, qdot_1..qdot_d``: the model's free rollout (no input, no external force)
  from the first training state over the rest of the clip, by the project's velocity-Verlet scheme at the
  frame interval (paper Eq. 8; :func:`lagsplat.dynamics.integrators.rollout`).

Units: ``q`` in the chart's whitened units, ``qdot`` in chart units per second. Numbers are written with 17
significant digits, so a reader gets the float64 values back.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import torch

from lagsplat.chart import Chart
from lagsplat.dynamics.integrators import rollout
from lagsplat.io.atomic import atomic_write
from lagsplat.io.clip import HELD_OUT, TRAIN
from lagsplat.timeseries import central_difference_velocity, forward_difference_velocity, gaussian_smooth

__all__ = ["SPLIT_NAMES", "write_csv", "chart_velocity", "trajectory_columns", "free_rollout", "rollout_columns"]

SPLIT_NAMES = {TRAIN: "train", HELD_OUT: "held_out"}
"""The ``split`` column's labels."""


def write_csv(path: str | Path, columns: Mapping[str, Sequence]) -> Path:
    """Write equal-length ``columns`` (name -> values) as a CSV with a header row, atomically.

    Floats are written with 17 significant digits (``nan`` for a missing value), strings as they are.

    Raises:
        ValueError: if the columns differ in length, or a name or string holds a comma or a line break.
    """
    names = list(columns)
    cols = [np.asarray(columns[n]) for n in names]
    n = {len(c) for c in cols}
    if len(n) > 1:
        raise ValueError(f"{path}: columns of different lengths {sorted(n)}")
    for s in names + [str(v) for c in cols if c.dtype.kind in "US" for v in c]:
        if any(ch in s for ch in ",\n\r"):
            raise ValueError(f"{path}: {s!r} holds a comma or a line break")
    fmt = [(lambda v: str(v)) if c.dtype.kind in "USO" else (lambda v: f"{float(v):.17g}") for c in cols]
    lines = [",".join(names)] + [",".join(f(c[i]) for f, c in zip(fmt, cols)) for i in range(len(cols[0]) if cols else 0)]
    with atomic_write(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n")
    return Path(path)


def chart_velocity(q: np.ndarray, dt: float, episode: np.ndarray | None = None, sigma: float = 0.0) -> np.ndarray:
    """``qdot [T,d]`` of a chart trajectory ``q [T,d]``, per episode, as Stage 2 reads velocities.

    The trajectory is Gaussian-smoothed over ``sigma`` frames (:func:`~lagsplat.timeseries.gaussian_smooth`,
    Stage 2's ``stage2.sigma``), then differenced: the central difference ``(q_{s+1} - q_{s-1}) / 2 dt`` inside
    (:func:`~lagsplat.timeseries.central_difference_velocity`), the second-order one-sided difference at both
    ends (:func:`~lagsplat.timeseries.forward_difference_velocity`, the rule of every rollout's initial velocity;
    mirrored at the end). An episode of fewer than 3 frames gets NaN.

    Args:
        q: ``[T,d]`` chart states; dt: frame interval, s; episode: ``[T]`` recording index (``None``: one).
        sigma: smoothing, frames (0: none).

    Returns:
        float64 ``[T,d]``, chart units per second.

    Raises:
        ValueError: from the signal helpers for non-finite input or ``dt <= 0``.
    """
    q = np.asarray(q, np.float64)
    ep = np.zeros(len(q), int) if episode is None else np.asarray(episode)
    out = np.full_like(q, np.nan)
    cuts = np.flatnonzero(np.diff(ep) != 0) + 1
    for idx in np.split(np.arange(len(q)), cuts):
        if len(idx) < 3:
            continue
        qs = gaussian_smooth(q[idx], sigma)
        v = np.empty_like(qs)
        v[1:-1] = central_difference_velocity(qs, dt, 1)[0]
        v[0] = forward_difference_velocity(qs[:3], dt)[0]
        v[-1] = -forward_difference_velocity(qs[::-1][:3], dt)[0]
        out[idx] = v
    return out


def trajectory_columns(chart: Chart, sigma: float) -> dict[str, np.ndarray]:
    """The columns of ``trajectory.csv`` (module docstring): ``t`` (s, from the clip's timestamps), ``q_i``, ``qdot_i``
    (:func:`chart_velocity` with Stage 2's smoothing ``sigma``, frames), ``u_j`` (the measured inputs, if any),
    ``split`` and, for several recordings, ``episode``."""
    dt = float(np.median(np.diff(chart.t)))
    qdot = chart_velocity(chart.q, dt, chart.episode, sigma)
    cols: dict[str, np.ndarray] = {"t": np.asarray(chart.t, np.float64)}
    cols.update({f"q_{i + 1}": chart.q[:, i] for i in range(chart.d)})
    cols.update({f"qdot_{i + 1}": qdot[:, i] for i in range(chart.d)})
    cols.update({f"u_{j + 1}": chart.u[:, j] for j in range(chart.n_u)})
    cols["split"] = np.array([SPLIT_NAMES.get(int(s), str(int(s))) for s in chart.split])
    if len(np.unique(chart.episode)) > 1:
        cols["episode"] = np.asarray(chart.episode, np.int64)
    return cols


def free_rollout(model, chart: Chart, sigma: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The model's free rollout from the first training state to the clip's last frame (paper Eq. 8).

    Initial state: the first frame of the first training segment of the chart smoothed over ``sigma`` frames,
    its velocity by the forward difference over the next two frames (the rule of
    :func:`lagsplat.dynamics.integrators.initial_state`, here in float64); step: the median frame interval.

    Returns:
        ``(t [n], q [n,d], qdot [n,d])``, float64, ``t`` in seconds on the clip's clock.

    Raises:
        ValueError: if the chart has no training segment of at least 3 frames.
    """
    seg = next((s for s in chart.segments(TRAIN) if len(s) >= 3), None)
    if seg is None:
        raise ValueError("the chart has no training segment of 3 frames or more to start a rollout from")
    dt = float(np.median(np.diff(chart.t)))
    qs = gaussian_smooth(chart.q[seg], sigma)
    q0 = qs[0]
    v0 = forward_difference_velocity(qs[:3], dt)[0]
    n = len(chart.t) - int(seg[0])
    with torch.no_grad():
        Q, Vq = rollout(model, torch.as_tensor(q0[None]), torch.as_tensor(v0[None]), dt, n)
    return chart.t[seg[0]] + dt * np.arange(n), Q[0].double().numpy(), Vq[0].double().numpy()


def rollout_columns(t: np.ndarray, q: np.ndarray, qdot: np.ndarray) -> dict[str, np.ndarray]:
    """The columns of ``rollout.csv``: ``t`` (s), ``q_1..q_d``, ``qdot_1..qdot_d``."""
    d = q.shape[1]
    return {"t": t, **{f"q_{i + 1}": q[:, i] for i in range(d)}, **{f"qdot_{i + 1}": qdot[:, i] for i in range(d)}}
