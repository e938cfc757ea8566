"""Where the gap shows in time: free rollouts and the one-step residual against their floors, and the flagged windows.

The *time* aspect of :mod:`lagsplat.diagnose.where` (see its module docstring):
free multi-step rollouts from the encoded state, read in the visibility metric
``dq^T G_bar dq`` (the image MSE they cause to first order, paper Eq. 6)
against the frame's AE floor plus the chart noise, and the residual
generalized force in noise units; windows are the runs where both exceed
``floor_factor`` times their floor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lagsplat import metrics, timeseries
from lagsplat.diagnose.where import WhereConfig, residual_z2, split_segments, symmetric
from lagsplat.dynamics.integrators import actuation_schedule, initial_state, rollout
from lagsplat.io.clip import TRAIN

__all__ = ["TimeLocalisation", "time_localisation"]


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``(start, stop)`` (stop exclusive) of the runs of ``True`` in a 1-D bool array."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    edges = np.flatnonzero(m[1:] != m[:-1])
    return [(int(a), int(b)) for a, b in zip(edges[0::2], edges[1::2])]


@dataclass
class TimeLocalisation:
    """The gap along time (see the module docstring).

    Attributes:
        frames: int ``[m]`` chart frame indices analysed (the split's segments).
        t: float ``[m]`` their times, s.
        segment: int ``[m]`` segment of each frame.
        p_enc: ``[m]`` smoothed encoded coordinate on the most visible direction.
        e_roll: ``[m]`` mean rollout error ``dq^T G_bar dq`` over the rollouts covering
            the frame (image-MSE units; NaN where none covers it).
        floor: ``[m]`` its floor: the frame's AE MSE plus the chart noise in ``G_bar``.
        ratio_roll: ``e_roll / floor``.
        z2: ``[m]`` residual in noise units (NaN where the residual has no sample).
        flag_roll, flag_res, flag: bool ``[m]``: rollout, residual, both.
        windows: the flagged time windows (dicts, JSON-ready).
        period_s: natural period used, s; horizon: rollout length, frames.
        rollouts: ``(frame [N], q_sim [N,d])`` every simulated state (for the image maps).
        dq_dir: ``[d]`` mean over rollout states of ``(V^T dq)^2`` (eigenbasis of ``G_bar``).
    """

    frames: np.ndarray
    t: np.ndarray
    segment: np.ndarray
    p_enc: np.ndarray
    e_roll: np.ndarray
    floor: np.ndarray
    ratio_roll: np.ndarray
    z2: np.ndarray
    flag_roll: np.ndarray
    flag_res: np.ndarray
    flag: np.ndarray
    windows: list[dict[str, Any]]
    period_s: float
    horizon: int
    rollouts: tuple[np.ndarray, np.ndarray] = field(repr=False, default=(np.zeros(0, int), np.zeros((0, 1))))
    dq_dir: np.ndarray = field(default_factory=lambda: np.zeros(0))
    p_sim: list[tuple[np.ndarray, np.ndarray]] = field(repr=False, default_factory=list)

    def summary(self) -> dict[str, Any]:
        """JSON-ready numbers (no per-frame arrays)."""
        dt = float(np.median(np.diff(self.t))) if len(self.t) > 1 else 0.0
        dur = float(len(self.frames)) * dt
        fin = np.isfinite(self.z2)
        return {
            "n_frames": int(len(self.frames)),
            "duration_s": dur,
            "period_s": float(self.period_s),
            "rollout_horizon_frames": int(self.horizon),
            "share_flagged_rollout": float(np.mean(self.flag_roll)) if len(self.flag_roll) else 0.0,
            "share_flagged_residual": float(np.mean(self.flag_res[fin])) if fin.any() else 0.0,
            "share_flagged_both": float(np.mean(self.flag)) if len(self.flag) else 0.0,
            "median_rollout_over_floor": float(np.nanmedian(self.ratio_roll)) if np.isfinite(self.ratio_roll).any() else None,
            "median_residual_z2": float(np.nanmedian(self.z2)) if fin.any() else None,
            "windows": self.windows,
        }


@dataclass
class _RolloutLog:
    """What the rollouts of every segment leave beside the per-frame error (accumulated in rollout order)."""

    dq_acc: np.ndarray
    dq_n: int = 0
    frames: list[np.ndarray] = field(default_factory=list)
    states: list[np.ndarray] = field(default_factory=list)
    p_sim: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)


def _period_frames(res: Any | None, chart: Any, segs: list[np.ndarray], sigma: float, top: np.ndarray, dt: float) -> float:
    """The natural period in frames: the residual's dominant frequency, else the spectral peak of the longest segment."""
    f = float(getattr(res, "f_dominant_hz", float("nan"))) if res is not None else float("nan")
    if not (math.isfinite(f) and f > 0):
        longest = max(segs, key=len)
        f = timeseries.spectral_peak_frequency(metrics.project(timeseries.gaussian_smooth(chart.q[longest], sigma), top), dt)
    return 1.0 / (f * dt)


def _segment_errors(
    model: Any, chart: Any, seg: np.ndarray, sigma: float, H: int, step: int, dt: float, G: np.ndarray, V: np.ndarray, top: np.ndarray,
    log: _RolloutLog,
) -> tuple[np.ndarray, np.ndarray]:
    """Free rollouts over one segment: ``(smoothed q [n,d], mean rollout error per frame [n], NaN where none covers it)``."""
    q_s = timeseries.gaussian_smooth(chart.q[seg], sigma)
    n = len(q_s)
    h = min(H, n - 2)
    first = metrics.rollout_start(sigma, n, h + 2)  # past the smoothing's edge (biased velocity)
    starts = np.arange(first, n - h - 2 + 1, step) if n - h - 2 >= 0 else np.zeros(0, int)
    acc = np.zeros(n)
    cnt = np.zeros(n)
    if len(starts):
        q0, v0 = initial_state(q_s, starts, dt)
        u = chart.u[seg]
        u_w = np.stack([u[s : s + h] for s in starts]) if u.shape[1] else None
        sim, _ = rollout(model, q0, v0, dt, h, u=actuation_schedule(u_w, dt))
        sim = sim.double().numpy()
        for i, s in enumerate(starts):
            dq = sim[i] - q_s[s : s + h]
            ok = np.isfinite(dq).all(1)
            e = np.einsum("ti,ij,tj->t", np.where(ok[:, None], dq, 0), G, np.where(ok[:, None], dq, 0))
            acc[s : s + h] += np.where(ok, e, 0.0)
            cnt[s : s + h] += ok
            log.frames.append(seg[s : s + h][ok])
            log.states.append(sim[i][ok])
            proj = np.where(ok[:, None], dq, 0) @ V
            log.dq_acc += (proj**2).sum(0)
            log.dq_n += int(ok.sum())
            log.p_sim.append((chart.t[seg[s : s + h]], sim[i] @ top))
    with np.errstate(invalid="ignore", divide="ignore"):
        e_roll = np.where(cnt > 0, acc / np.maximum(cnt, 1), np.nan)
    return q_s, e_roll


def _frame_z2(res: Any | None, chart: Any, frames: np.ndarray, dt: float) -> np.ndarray:
    """The residual in noise units on the analysed frames ``[m]`` (NaN where the residual has no sample)."""
    z2 = np.full(len(frames), np.nan)
    if res is not None and res.n:
        pos = {int(fi): i for i, fi in enumerate(frames)}
        idx = np.searchsorted(chart.t, res.t)
        idx = np.clip(idx, 0, len(chart.t) - 1)
        zz = residual_z2(res)
        for j, fi in enumerate(idx):
            if abs(chart.t[fi] - res.t[j]) < 0.25 * dt and int(fi) in pos:
                z2[pos[int(fi)]] = zz[j]
    return z2


def _windows(flag: np.ndarray, seg_a: np.ndarray, t_a: np.ndarray, ratio: np.ndarray, z2: np.ndarray, n_segs: int, min_len: int) -> list[dict[str, Any]]:
    """Runs of the combined flag inside each segment, merged over gaps shorter than ``min_len`` frames, short ones dropped; worst first."""
    windows = []
    for k in range(n_segs):
        idx = np.flatnonzero(seg_a == k)
        merged: list[list[int]] = []
        for a, b in _runs(flag[idx]):
            if merged and a - merged[-1][1] < min_len:
                merged[-1][1] = b
            else:
                merged.append([a, b])
        for a, b in merged:
            if b - a < min_len:
                continue
            sel = idx[a:b]
            windows.append({
                "t_start_s": float(t_a[sel[0]]), "t_end_s": float(t_a[sel[-1]]), "segment": int(k),
                "n_frames": int(len(sel)), "peak_rollout_over_floor": float(np.nanmax(ratio[sel])),
                "mean_residual_z2": float(np.nanmean(z2[sel])) if np.isfinite(z2[sel]).any() else None,
            })  # fmt: skip
    windows.sort(key=lambda w: -(w["peak_rollout_over_floor"] or 0.0) * (w["mean_residual_z2"] or 1.0))
    return windows


def time_localisation(model: Any, chart: Any, res: Any | None = None, cfg: WhereConfig | None = None, which: int | None = TRAIN) -> TimeLocalisation:
    """Rollout error and one-step residual over time, against the AE floor.

    Args:
        model: fitted model (``acceleration(q, qdot, f_ext, u=...)``).
        chart: the :class:`~lagsplat.chart.Chart` (``q``, ``t``, ``G_bar``, ``ae_mse``, ``u``).
        res: the :class:`~lagsplat.diagnose.residual_data.Residual` of ``model`` on the
            same split (``None``: no residual flag, only the rollout).
        cfg: settings.
        which: split (0 train, 1 held-out, ``None`` all frames).

    Returns:
        The :class:`TimeLocalisation`.

    Raises:
        ValueError: if no segment of the split holds one rollout (horizon + 3 frames).
    """
    cfg = cfg or WhereConfig()
    dt = float(np.median(np.diff(chart.t)))
    G = symmetric(chart.G_bar)
    lam, V = np.linalg.eigh(G)
    order = np.argsort(lam)[::-1]
    lam, V = lam[order], V[:, order]
    top = V[:, 0]
    segs = [s for s in split_segments(chart, which) if len(s) >= 11]
    if not segs:
        raise ValueError("time_localisation: no segment of the split has 11 frames")
    period = _period_frames(res, chart, segs, cfg.sigma, top, dt)  # frames
    H = int(max(8, round(cfg.horizon_periods * period)))
    step = int(max(1, round(cfg.start_every_periods * period)))
    noise = np.zeros(chart.d)
    if res is not None:
        noise = np.asarray(res.noise_q, np.float64)
    noise_G = float(noise**2 @ np.diag(G))
    ae = np.asarray(chart.ae_mse, np.float64)

    log = _RolloutLog(np.zeros(chart.d))
    p_enc, e_roll = [], []
    for seg in segs:
        q_s, e = _segment_errors(model, chart, seg, cfg.sigma, H, step, dt, G, V, top, log)
        p_enc.append(q_s @ top)
        e_roll.append(e)
    frames_a = np.concatenate(segs)
    t_a = np.concatenate([chart.t[seg] for seg in segs])
    seg_a = np.concatenate([np.full(len(seg), k) for k, seg in enumerate(segs)])
    e_a = np.concatenate(e_roll)
    fl = np.maximum(np.concatenate([ae[seg] + noise_G for seg in segs]), 1e-12)
    ratio = e_a / fl
    z2 = _frame_z2(res, chart, frames_a, dt)
    flag_roll = np.nan_to_num(ratio, nan=0.0) > cfg.floor_factor
    flag_res = np.nan_to_num(z2, nan=0.0) > cfg.floor_factor
    flag = flag_roll & flag_res if res is not None else flag_roll
    windows = _windows(flag, seg_a, t_a, ratio, z2, len(segs), max(1, int(round(cfg.min_window_periods * period))))
    return TimeLocalisation(
        frames=frames_a, t=t_a, segment=seg_a, p_enc=np.concatenate(p_enc), e_roll=e_a, floor=fl, ratio_roll=ratio,
        z2=z2, flag_roll=flag_roll, flag_res=flag_res, flag=flag, windows=windows, period_s=float(period * dt), horizon=H,
        rollouts=(np.concatenate(log.frames) if log.frames else np.zeros(0, int), np.concatenate(log.states) if log.states else np.zeros((0, chart.d))),
        dq_dir=log.dq_acc / max(log.dq_n, 1), p_sim=log.p_sim,
    )  # fmt: skip
