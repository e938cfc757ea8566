"""When Stage 1 has converged: the loss and the chart both stalled, or the wall-time cap reached.

A fixed step count is too many for a clean clip and too few for a cluttered
one. :class:`Plateau` is asked at the recycling cadence of Stage 1 (paper
App. C) and says stop when, over the last ``patience`` steps, the smoothed
loss improved by less than ``tol`` (relative) *and* the chart stopped moving:
the encodings of a fixed set of probe frames are an affine image of those of
the previous check (``R^2 > 1 - chart_tol``), so Stage 2 would see the same
trajectory up to the whitening. A wall-time cap stops it regardless.
"""

from __future__ import annotations

import time

import numpy as np

__all__ = ["Plateau", "affine_r2"]


def affine_r2(z_now: np.ndarray, z_prev: np.ndarray) -> float:
    """``R^2`` of the least-squares affine map ``z_prev -> z_now`` (``[P,d]`` each); 1: the same chart up to an affine map."""
    A = np.concatenate([z_prev, np.ones((len(z_prev), 1))], 1)
    coef, *_ = np.linalg.lstsq(A, z_now, rcond=None)
    res = ((z_now - A @ coef) ** 2).sum()
    tot = ((z_now - z_now.mean(0)) ** 2).sum()
    return float(1.0 - res / tot) if tot > 0 else 1.0


class Plateau:
    """Stop rule of Stage 1 (module docstring).

    Args:
        patience: steps over which the loss must improve (0: never stop on a plateau).
        tol: relative improvement of the smoothed loss below which it has stalled.
        chart_tol: ``1 - R^2`` of the probe encodings below which the chart has stalled.
        max_seconds: wall-time cap (``None`` or ``<= 0``: none), from construction.
    """

    def __init__(self, patience: int, tol: float = 0.01, chart_tol: float = 1e-3, max_seconds: float | None = None) -> None:
        self.patience, self.tol, self.chart_tol = int(patience), float(tol), float(chart_tol)
        self.deadline = time.perf_counter() + max_seconds if max_seconds and max_seconds > 0 else None
        self.best: list[tuple[int, float]] = []  # (step, best smoothed loss so far)
        self.z_prev: np.ndarray | None = None

    def check(self, step: int, loss_ema: float, z_probe: np.ndarray) -> str | None:
        """Record a check at ``step``; return why to stop, or ``None`` to go on."""
        if self.deadline is not None and time.perf_counter() > self.deadline:
            return "wall-time cap"
        best = min(loss_ema, self.best[-1][1]) if self.best else loss_ema
        self.best.append((step, best))
        chart_r2 = affine_r2(z_probe, self.z_prev) if self.z_prev is not None else 0.0
        self.z_prev = z_probe
        if self.patience <= 0:
            return None
        earlier = [b for s, b in self.best if s <= step - self.patience]
        if not earlier:
            return None
        gain = (earlier[-1] - best) / max(abs(earlier[-1]), 1e-12)
        if gain < self.tol and chart_r2 > 1.0 - self.chart_tol:
            return f"plateau: loss {100 * gain:.2f} % better over {self.patience} steps, chart R^2 {chart_r2:.5f}"
        return None
