"""Where the identified simulation departs from the recording.

The gap between a fitted model and the video is localised four ways, each
against what the autoencoder floor already explains (the decoder cannot
reproduce a frame better than ``decode(encode(frame))``, paper §3.2, so only
the error in excess of that floor is the simulation's):

* **time** (:func:`time_localisation`): free multi-step rollouts (velocity
  Verlet from the encoded state, :func:`lagsplat.dynamics.integrators.rollout`,
  initial state as in :mod:`lagsplat.evaluate`) started every
  ``start_every_periods`` natural periods from past the smoothing's edge
  (:func:`lagsplat.timeseries.smoothing_edge`) and run ``horizon_periods``; their
  deviation ``dq = q_sim - q_enc`` is read in the visibility metric,
  ``e_roll = dq^T G_bar dq``, which is the image MSE the deviation causes to
  first order (``G_bar = E[J^T J]`` per pixel and channel, paper Eq. 6), and
  compared with the frame's AE floor ``ae_mse`` plus the chart noise read in
  the same metric. The one-step residual is the residual generalized force
  ``r`` of :mod:`lagsplat.diagnose.residual` in units of its noise level
  (``z2 = mean_j (r_j / noise_r_j)^2``, about 1 where the model explains the
  motion up to the chart noise, the latent image of the AE floor). Windows are
  the runs where both exceed ``floor_factor`` times their floor.
* **state** (:func:`state_localisation`): the phase portrait of the most
  visible coordinate ``p = e^T q`` (``e`` the top eigenvector of ``G_bar``)
  in the units of the oscillation (``x = (p - p_c) / S``, ``y = pdot / (w S)``,
  ``S`` the 95th percentile of the radius), partitioned into *near rest*
  (radius below ``rest_radius``), *turning points* (``|y| < turning_ratio *
  radius``), *high speed* (``|pdot|`` above its ``high_speed_quantile``) and
  the rest; per region, the share of the residual energy ``sum z2`` against
  the share of samples.
* **latent directions** (:func:`latent_localisation`): along each eigenvector
  ``e_k`` of ``G_bar`` (eigenvalue ``lambda_k``, its visibility), the residual
  acceleration ``M^-1 r`` and the rollout deviation, raw and weighted by
  ``lambda_k`` (their share of the image-visible gap).
* **image** (:func:`image_localisation`): per-pixel error maps of the rendered
  rollouts against the real frames minus the AE reconstruction's error on the
  same frames (the excess), attributed to the Gaussians that render each pixel
  by their compositing weights ``T_i a_i`` (the rasteriser's rule,
  :meth:`lagsplat.force.ForceTransport.compositing_weights`), averaged between
  the encoded and the simulated state, plus the share left to the background.

:func:`lagsplat.diagnose.localise.localise` runs all four (the image one is there too); :func:`lagsplat.diagnose.where_plots.plot_where` draws one figure per aspect.
Everything reads only the frames of the chosen split (the diagnosis' training
frames by default), so the held-out frames stay untouched for the gap.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lagsplat import metrics, timeseries
from lagsplat.dynamics.integrators import actuation_schedule, initial_state, rollout
from lagsplat.io.clip import HELD_OUT, TRAIN

__all__ = [
    "WhereConfig",
    "TimeLocalisation",
    "StateLocalisation",
    "LatentLocalisation",
    "split_code",
    "time_localisation",
    "state_localisation",
    "latent_localisation",
    "REGIONS",
]

#: Phase-portrait regions, in the order they are assigned (a sample takes the first that applies).
REGIONS = ("near_rest", "turning_points", "high_speed", "other")


@dataclass
class WhereConfig:
    """Settings of the localisation (``conf/config.yaml``, group ``diagnose.where``).

    Attributes:
        horizon_periods: length of each free rollout, natural periods.
        start_every_periods: spacing of the rollout starts, natural periods.
        sigma: Gaussian smoothing of the encoded trajectory before the initial
            state is read, frames (as :class:`lagsplat.evaluate.EvalConfig`).
        floor_factor: a frame is flagged when the rollout error (resp. the
            residual) exceeds this many times its floor.
        min_window_periods: flagged runs shorter than this are dropped, and runs
            closer than this are merged (natural periods).
        rest_radius: phase-portrait radius (units of ``S``) below which a sample is "near rest".
        turning_ratio: ``|y| / radius`` below which a sample is at a turning point.
        high_speed_quantile: quantile of ``|pdot|`` above which a sample is at high speed.
        n_image_frames: rollout frames rendered for the image maps (0: no image analysis).
        pixel_chunk: pixels per call of the compositing weights (memory bound).
        top_gaussians: Gaussians listed in the report.
        moving_fraction: a Gaussian *moves* when ``|J_i|_F`` (pixels per unit whitened
            ``q``) is at least this fraction of the 99th percentile over the Gaussians
            (trained decoders give background primitives small, non-zero ``J_i``).
    """

    horizon_periods: float = 1.0
    start_every_periods: float = 0.25
    sigma: float = 1.0
    floor_factor: float = 2.0
    min_window_periods: float = 0.25
    rest_radius: float = 0.2
    turning_ratio: float = 0.38
    high_speed_quantile: float = 0.75
    n_image_frames: int = 48
    pixel_chunk: int = 2048
    top_gaussians: int = 10
    moving_fraction: float = 0.1

    @classmethod
    def from_mapping(cls, m: Mapping[str, Any] | None) -> WhereConfig:
        """Build from a (Hydra) mapping; unknown keys raise ``KeyError``."""
        from lagsplat.train.config import dataclass_from_mapping

        return dataclass_from_mapping(cls, dict(m or {}), "diagnose.where")


def split_code(split: str | int | None) -> int | None:
    """``"train"`` -> 0, ``"held_out"`` -> 1, ``"all"`` / ``None`` -> ``None``.

    Raises:
        ValueError: on another name.
    """
    if split is None or isinstance(split, int):
        return split
    names = {"train": TRAIN, "held_out": HELD_OUT, "all": None}
    if split not in names:
        raise ValueError(f"unknown split {split!r}; expected one of {sorted(names)}")
    return names[split]


def _segments(chart: Any, which: int | None) -> list[np.ndarray]:
    if which is None:
        from lagsplat.io.clip import segments

        return segments(np.zeros(len(chart.t), np.int8), 0, chart.episode)
    return chart.segments(int(which))


def _sym(G: np.ndarray) -> np.ndarray:
    G = np.asarray(G, np.float64)
    return 0.5 * (G + G.T)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``(start, stop)`` (stop exclusive) of the runs of ``True`` in a 1-D bool array."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    edges = np.flatnonzero(m[1:] != m[:-1])
    return [(int(a), int(b)) for a, b in zip(edges[0::2], edges[1::2])]


def _kernel_norm(sigma: float, order: int) -> float:
    """``|g|_2`` of the discrete Gaussian derivative kernel of this order (the residual's noise propagation)."""
    from scipy.ndimage import gaussian_filter1d

    n = int(8 * sigma) + 1
    imp = np.zeros(2 * n + 1)
    imp[n] = 1.0
    return float(np.linalg.norm(gaussian_filter1d(imp, sigma, order=order, mode="constant", truncate=6.0)))


def residual_z2(res: Any) -> np.ndarray:
    """Residual energy in noise units per sample, ``mean_j (r_j / noise_r_j)^2`` ``[n]`` (about 1 for chart noise)."""
    return np.mean((np.asarray(res.r) / np.asarray(res.noise_r)[None]) ** 2, axis=1)


# ---------------------------------------------------------------------- time
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


def time_localisation(model: Any, chart: Any, res: Any | None = None, cfg: WhereConfig | None = None, which: int | None = TRAIN) -> TimeLocalisation:
    """Rollout error and one-step residual over time, against the AE floor.

    Args:
        model: fitted model (``acceleration(q, qdot, f_ext, u=...)``).
        chart: the :class:`~lagsplat.chart.Chart` (``q``, ``t``, ``G_bar``, ``ae_mse``, ``u``).
        res: the :class:`~lagsplat.diagnose.residual.Residual` of ``model`` on the
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
    G = _sym(chart.G_bar)
    lam, V = np.linalg.eigh(G)
    order = np.argsort(lam)[::-1]
    lam, V = lam[order], V[:, order]
    top = V[:, 0]
    segs = [s for s in _segments(chart, which) if len(s) >= 11]
    if not segs:
        raise ValueError("time_localisation: no segment of the split has 11 frames")
    f = float(getattr(res, "f_dominant_hz", float("nan"))) if res is not None else float("nan")
    if not (math.isfinite(f) and f > 0):
        longest = max(segs, key=len)
        f = timeseries.spectral_peak_frequency(metrics.project(timeseries.gaussian_smooth(chart.q[longest], cfg.sigma), top), dt)
    period = 1.0 / (f * dt)  # frames
    H = int(max(8, round(cfg.horizon_periods * period)))
    step = int(max(1, round(cfg.start_every_periods * period)))
    noise = np.zeros(chart.d)
    if res is not None:
        noise = np.asarray(res.noise_q, np.float64)
    noise_G = float(noise**2 @ np.diag(G))
    ae = np.asarray(chart.ae_mse, np.float64)

    frames, tt, segid, p_enc, e_roll, floor = [], [], [], [], [], []
    roll_f, roll_q, dq_acc, dq_n, p_sims = [], [], np.zeros(chart.d), 0, []
    for k, seg in enumerate(segs):
        q_s = timeseries.gaussian_smooth(chart.q[seg], cfg.sigma)
        n = len(q_s)
        h = min(H, n - 2)
        first = metrics.rollout_start(cfg.sigma, n, h + 2)  # past the smoothing's edge (biased velocity)
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
                roll_f.append(seg[s : s + h][ok])
                roll_q.append(sim[i][ok])
                proj = np.where(ok[:, None], dq, 0) @ V
                dq_acc += (proj**2).sum(0)
                dq_n += int(ok.sum())
                p_sims.append((chart.t[seg[s : s + h]], sim[i] @ top))
        with np.errstate(invalid="ignore", divide="ignore"):
            e_roll.append(np.where(cnt > 0, acc / np.maximum(cnt, 1), np.nan))
        frames.append(seg)
        tt.append(chart.t[seg])
        segid.append(np.full(n, k))
        p_enc.append(q_s @ top)
        floor.append(ae[seg] + noise_G)
    frames_a = np.concatenate(frames)
    t_a = np.concatenate(tt)
    e_a = np.concatenate(e_roll)
    fl = np.maximum(np.concatenate(floor), 1e-12)
    ratio = e_a / fl
    z2 = np.full(len(frames_a), np.nan)
    if res is not None and res.n:
        pos = {int(fi): i for i, fi in enumerate(frames_a)}
        idx = np.searchsorted(chart.t, res.t)
        idx = np.clip(idx, 0, len(chart.t) - 1)
        zz = residual_z2(res)
        for j, fi in enumerate(idx):
            if abs(chart.t[fi] - res.t[j]) < 0.25 * dt and int(fi) in pos:
                z2[pos[int(fi)]] = zz[j]
    flag_roll = np.nan_to_num(ratio, nan=0.0) > cfg.floor_factor
    flag_res = np.nan_to_num(z2, nan=0.0) > cfg.floor_factor
    flag = flag_roll & flag_res if res is not None else flag_roll

    # windows: runs of the combined flag inside each segment, merged over short gaps, short ones dropped
    min_len = max(1, int(round(cfg.min_window_periods * period)))
    seg_a = np.concatenate(segid)
    windows = []
    for k in range(len(segs)):
        idx = np.flatnonzero(seg_a == k)
        runs = _runs(flag[idx])
        merged: list[list[int]] = []
        for a, b in runs:
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
    return TimeLocalisation(
        frames=frames_a, t=t_a, segment=seg_a, p_enc=np.concatenate(p_enc), e_roll=e_a, floor=fl, ratio_roll=ratio,
        z2=z2, flag_roll=flag_roll, flag_res=flag_res, flag=flag, windows=windows, period_s=float(period * dt), horizon=H,
        rollouts=(np.concatenate(roll_f) if roll_f else np.zeros(0, int), np.concatenate(roll_q) if roll_q else np.zeros((0, chart.d))),
        dq_dir=dq_acc / max(dq_n, 1), p_sim=p_sims,
    )  # fmt: skip


# ---------------------------------------------------------------------- state
@dataclass
class StateLocalisation:
    """The residual over the phase portrait (see the module docstring).

    Attributes:
        x, y: ``[n]`` normalised position and velocity of each residual sample.
        z2: ``[n]`` residual in noise units.
        region: int ``[n]`` index into :data:`REGIONS`.
        regions: per region: ``sample_share``, ``residual_share`` (of ``sum z2``),
            ``excess_share`` (of ``sum max(z2 - 1, 0)``), ``enrichment``
            (``residual_share / sample_share``), ``mean_z2``.
        scale: ``{"S", "p_centre", "omega"}`` used for the normalisation; ``bounds``: region boundaries.
    """

    x: np.ndarray
    y: np.ndarray
    z2: np.ndarray
    region: np.ndarray
    regions: dict[str, dict[str, float]]
    scale: dict[str, float]
    bounds: dict[str, float]

    def summary(self) -> dict[str, Any]:
        """JSON-ready numbers."""
        top = max(self.regions, key=lambda k: self.regions[k]["enrichment"] if self.regions[k]["sample_share"] > 0 else -1)
        return {"regions": self.regions, "most_enriched": top, "scale": self.scale, "bounds": self.bounds}


def state_localisation(res: Any, cfg: WhereConfig | None = None) -> StateLocalisation:
    """Residual share per phase-portrait region (turning points, high speed, near rest, other).

    Args:
        res: the :class:`~lagsplat.diagnose.residual.Residual`.
        cfg: settings.

    Returns:
        The :class:`StateLocalisation`.

    Raises:
        ValueError: if the residual has no sample.
    """
    cfg = cfg or WhereConfig()
    if res.n == 0:
        raise ValueError("state_localisation: empty residual")
    e = metrics.top_direction(res.G)
    p = res.q @ e
    v = res.qdot @ e
    f = float(res.f_dominant_hz)
    if not (math.isfinite(f) and f > 0):
        f = 1.0 / (res.n * res.dt)
    w = 2 * math.pi * f
    pc = float(np.median(p))
    rad = np.hypot(p - pc, v / w)
    S = float(np.quantile(rad, 0.95)) or 1.0
    x, y = (p - pc) / S, v / (w * S)
    r = np.hypot(x, y)
    vq = float(np.quantile(np.abs(y), cfg.high_speed_quantile))
    region = np.full(res.n, 3)
    rest = r < cfg.rest_radius
    turning = ~rest & (np.abs(y) < cfg.turning_ratio * r)
    fast = ~rest & ~turning & (np.abs(y) >= vq)
    region[fast] = 2
    region[turning] = 1
    region[rest] = 0
    z2 = residual_z2(res)
    tot = float(z2.sum()) or 1.0
    exc = np.maximum(z2 - 1.0, 0.0)
    tot_exc = float(exc.sum())
    regions = {}
    for i, name in enumerate(REGIONS):
        m = region == i
        ss = float(m.mean())
        rs = float(z2[m].sum() / tot)
        regions[name] = {
            "sample_share": ss, "residual_share": rs, "excess_share": float(exc[m].sum() / tot_exc) if tot_exc > 0 else 0.0,
            "enrichment": rs / ss if ss > 0 else float("nan"), "mean_z2": float(z2[m].mean()) if m.any() else float("nan"),
        }  # fmt: skip
    return StateLocalisation(
        x=x, y=y, z2=z2, region=region, regions=regions, scale={"S": S, "p_centre": pc, "omega": w},
        bounds={"rest_radius": cfg.rest_radius, "turning_ratio": cfg.turning_ratio, "high_speed_y": vq},
    )  # fmt: skip


# ---------------------------------------------------------------------- latent directions
@dataclass
class LatentLocalisation:
    """The gap along the eigenvectors of ``G_bar``.

    Attributes:
        eigenvalues: ``[d]`` of ``G_bar``, descending (visibility, image MSE per unit ``q^2``).
        directions: ``[d,d]`` columns: the eigenvectors.
        residual_ms: ``[d]`` mean square residual acceleration ``M^-1 r`` along each (per s^4).
        residual_noise: ``[d]`` its chart-noise level (mean square).
        residual_share, residual_share_G: raw and ``lambda``-weighted shares of the residual.
        rollout_ms: ``[d]`` mean square rollout deviation along each (``None`` without rollouts).
        rollout_share_G: its ``lambda``-weighted share.
    """

    eigenvalues: np.ndarray
    directions: np.ndarray
    residual_ms: np.ndarray
    residual_noise: np.ndarray
    residual_share: np.ndarray
    residual_share_G: np.ndarray
    rollout_ms: np.ndarray | None
    rollout_share_G: np.ndarray | None

    def summary(self) -> dict[str, Any]:
        """JSON-ready numbers, one entry per direction (most visible first)."""
        out = []
        vis = self.eigenvalues / max(float(self.eigenvalues.sum()), 1e-300)
        for k in range(len(self.eigenvalues)):
            out.append({
                "direction": [float(v) for v in self.directions[:, k]], "eigenvalue": float(self.eigenvalues[k]),
                "visibility_share": float(vis[k]), "residual_share": float(self.residual_share[k]),
                "residual_share_G": float(self.residual_share_G[k]),
                "residual_over_noise": float(self.residual_ms[k] / max(self.residual_noise[k], 1e-300)),
                "rollout_share_G": None if self.rollout_share_G is None else float(self.rollout_share_G[k]),
            })  # fmt: skip
        k_top = int(np.argmax(self.residual_share_G))
        return {"directions": out, "dominant": k_top}


def latent_localisation(res: Any, G_bar: np.ndarray, dq_dir: np.ndarray | None = None) -> LatentLocalisation:
    """Residual (and rollout deviation) per eigen-direction of ``G_bar``, raw and ``G_bar``-weighted.

    Args:
        res: the residual (``r``, ``M``, ``noise_q``, ``sigma``, ``dt``).
        G_bar: ``[d,d]`` visibility metric of the chart.
        dq_dir: ``[d]`` mean square rollout deviation in the eigenbasis
            (:attr:`TimeLocalisation.dq_dir`), or ``None``.

    Returns:
        The :class:`LatentLocalisation`.
    """
    G = _sym(G_bar)
    lam, V = np.linalg.eigh(G)
    order = np.argsort(lam)[::-1]
    lam, V = np.maximum(lam[order], 0.0), V[:, order]
    da = np.linalg.solve(res.M, res.r[..., None])[..., 0]  # [n,d] residual acceleration
    c = da @ V
    ms = np.mean(c**2, 0)
    s_a = np.asarray(res.noise_q, np.float64) * _kernel_norm(res.sigma, 2) / res.dt**2
    noise = (V**2).T @ (s_a**2)
    share = ms / max(float(ms.sum()), 1e-300)
    wG = lam * ms
    share_G = wG / max(float(wG.sum()), 1e-300)
    r_ms = r_sh = None
    if dq_dir is not None and len(dq_dir) == len(lam):
        r_ms = np.asarray(dq_dir, np.float64)
        wr = lam * r_ms
        r_sh = wr / max(float(wr.sum()), 1e-300)
    return LatentLocalisation(lam, V, ms, noise, share, share_G, r_ms, r_sh)


# ---------------------------------------------------------------------- image
