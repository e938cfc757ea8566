"""Where the identified simulation departs from the recording.

The gap between a fitted model and the video is localised four ways, each
against what the autoencoder floor already explains (the decoder cannot
reproduce a frame better than ``decode(encode(frame))``, paper §3.2, so only
the error in excess of that floor is the simulation's):

* **time** (:func:`~lagsplat.diagnose.where_time.time_localisation`): free multi-step rollouts (velocity
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
  :meth:`lagsplat.forces.transport.ForceTransport.compositing_weights`), averaged between
  the encoded and the simulated state, plus the share left to the background.

:func:`lagsplat.diagnose.localise.localise` runs all four (the image one is there too); :func:`lagsplat.diagnose.where_plots.plot_where` draws one figure per aspect.
Everything reads only the frames of the chosen split (the diagnosis' training
frames by default), so the held-out frames stay untouched for the gap.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from lagsplat import metrics
from lagsplat.diagnose.filters import kernel_norm
from lagsplat.io.clip import HELD_OUT, TRAIN
from lagsplat.diagnose.settings import WhereConfig

__all__ = [
    "WhereConfig",
    "StateLocalisation",
    "LatentLocalisation",
    "split_code",
    "split_segments",
    "symmetric",
    "residual_z2",
    "state_localisation",
    "latent_localisation",
    "REGIONS",
]

#: Phase-portrait regions, in the order they are assigned (a sample takes the first that applies).
REGIONS = ("near_rest", "turning_points", "high_speed", "other")




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


def split_segments(chart: Any, which: int | None) -> list[np.ndarray]:
    """Index arrays of the chart's contiguous segments of split ``which`` (``None``: every frame, split by episode only)."""
    if which is None:
        from lagsplat.io.clip import segments

        return segments(np.zeros(len(chart.t), np.int8), 0, chart.episode)
    return chart.segments(int(which))


def symmetric(G: np.ndarray) -> np.ndarray:
    """The symmetric part ``(G + G^T) / 2`` of a metric, float64 ``[d,d]``."""
    G = np.asarray(G, np.float64)
    return 0.5 * (G + G.T)


def residual_z2(res: Any) -> np.ndarray:
    """Residual energy in noise units per sample, ``mean_j (r_j / noise_r_j)^2`` ``[n]`` (about 1 for chart noise)."""
    return np.mean((np.asarray(res.r) / np.asarray(res.noise_r)[None]) ** 2, axis=1)


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
        res: the :class:`~lagsplat.diagnose.residual_data.Residual`.
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
            (:attr:`~lagsplat.diagnose.where_time.TimeLocalisation.dq_dir`), or ``None``.

    Returns:
        The :class:`LatentLocalisation`.
    """
    G = symmetric(G_bar)
    lam, V = np.linalg.eigh(G)
    order = np.argsort(lam)[::-1]
    lam, V = np.maximum(lam[order], 0.0), V[:, order]
    da = np.linalg.solve(res.M, res.r[..., None])[..., 0]  # [n,d] residual acceleration
    c = da @ V
    ms = np.mean(c**2, 0)
    s_a = np.asarray(res.noise_q, np.float64) * kernel_norm(res.sigma, 2) / res.dt**2
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
