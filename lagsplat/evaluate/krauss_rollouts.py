"""The soft-robot protocol's rollouts and scores: zero-order-hold rollouts under the measured pressures, the multi-step image error and the frequency windows (paper §4.4, Table 4; the windows and settings are :mod:`lagsplat.evaluate.krauss_windows`, the driver :func:`lagsplat.evaluate.krauss.evaluate_krauss`)."""

from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np
import torch

from lagsplat import metrics, timeseries
from lagsplat.dynamics.fast import cached_export, fast_rollout
from lagsplat.dynamics.integrators import fast_unavailable, verlet_step
from lagsplat.evaluate.krauss_windows import KraussEvalConfig, flat_intervals, mse_window_starts, n_states, peak_frequency

__all__ = ["rollout_zoh", "multistep_mse", "frequency_windows"]


@torch.no_grad()
def rollout_zoh(model: Any, q0: np.ndarray, v0: np.ndarray, dt: float, n_states_: int, P: np.ndarray | None) -> np.ndarray:
    """Velocity-Verlet rollouts with the pressure held over each step (the reference code).

    A model that the compiled path takes (:func:`lagsplat.dynamics.integrators.fast_unavailable`) is
    rolled out there (float64, same scheme); any other on the torch path below.

    Step ``i -> i+1`` evaluates both accelerations with ``P[:, i]``. A window
    whose step fails (non-finite state or a ``LinAlgError`` in the mass solve)
    is NaN from that step on and is not stepped any further.

    Args:
        model: exposes ``acceleration(q, qdot, f_ext, u=...)`` (a :class:`~lagsplat.models.lagrangian.Lagrangian`).
        q0, v0: ``[B, d]`` initial state (latent units, per second).
        dt: step, s.
        n_states_: states returned, the initial one included.
        P: ``[B, n_states_ - 1 (or more), n_u]`` pressure per step, ``[B, n_u]``
            frozen for the whole rollout, or ``None`` (no actuation).

    Returns:
        float64 ``[B, n_states_, d]``.
    """
    if fast_unavailable(model, torch.as_tensor(np.asarray(q0)), None, P) is None:  # the compiled path: same scheme, float64
        U = None if P is None or np.asarray(P).shape[-1] == 0 else np.asarray(P, np.float64)
        if U is not None and U.ndim == 3:
            U = U[:, : n_states_ - 1]
        return fast_rollout(cached_export(model), np.asarray(q0, np.float64), np.asarray(v0, np.float64), dt, n_states_, u=U)[0]
    q = torch.as_tensor(np.asarray(q0), dtype=torch.float32)
    v = torch.as_tensor(np.asarray(v0), dtype=torch.float32)
    B, d = q.shape
    out = np.full((B, n_states_, d), np.nan)
    out[:, 0] = q.numpy()
    alive = np.ones(B, bool)
    Pt = None if P is None or np.asarray(P).shape[-1] == 0 else torch.as_tensor(np.asarray(P), dtype=torch.float32)

    def u_at(i: int, idx: np.ndarray):
        if Pt is None:
            return None
        return Pt[idx] if Pt.ndim == 2 else Pt[idx, i]

    for i in range(n_states_ - 1):
        idx = np.flatnonzero(alive)
        if len(idx) == 0:
            break
        try:
            q1, v1 = verlet_step(model, q[idx], v[idx], dt, u=u_at(i, idx))
        except torch.linalg.LinAlgError:
            q1, v1 = torch.full((len(idx), d), float("nan")), torch.full((len(idx), d), float("nan"))
            for j, b in enumerate(idx):  # find the failing window(s); the others go on
                try:
                    q1[j : j + 1], v1[j : j + 1] = verlet_step(model, q[b : b + 1], v[b : b + 1], dt, u=u_at(i, np.array([b])))
                except torch.linalg.LinAlgError:
                    pass
        ok = torch.isfinite(q1).all(1) & torch.isfinite(v1).all(1)
        q[idx], v[idx] = q1.detach(), v1.detach()
        out[idx, i + 1] = q1.numpy()
        dead = idx[~ok.numpy()]
        out[dead, i + 1 :] = np.nan
        alive[dead] = False
    return out


def multistep_mse(
    q_raw: np.ndarray,
    frames: np.ndarray,
    P: np.ndarray | None,
    model: Any,
    decode_mse: Callable[[np.ndarray, np.ndarray], np.ndarray],
    dt: float,
    cfg: KraussEvalConfig,
) -> dict[str, Any]:
    """The multi-step image MSE of §9.1 on one validation clip.

    Args:
        q_raw: ``[n, d]`` unsmoothed whitened encodings of the validation frames.
        frames: ``[n, H, W, 3]`` uint8 validation frames.
        P: ``[n, n_u]`` raw pressures (smoothed here), or ``None``.
        model: the Lagrangian (eval mode).
        decode_mse: ``(q [M, d], frames [M, H, W, 3]) -> per-state MSE [M]``
            (decode, clamp to [0, 1], mean over C x H x W).
        dt: frame interval, s.
        cfg: protocol settings.

    Returns:
        Mapping with ``mse`` (the reported mean), ``per_step [H]``, ``sem``
        (standard error over windows, ``ddof = 1``), ``starts [N]``,
        ``horizon``, ``n_finite``, ``skip``.

    Raises:
        ValueError: if the clip is too short for the protocol.
    """
    n = len(q_raw)
    H = n_states(cfg.horizon_s, dt)
    skip = int(round(cfg.skip_s / dt))
    starts = mse_window_starts(n, H, skip, cfg.n_windows, cfg.seed)
    z_init = timeseries.gaussian_smooth(q_raw, cfg.sigma)
    q0 = z_init[starts]
    v0 = timeseries.forward_difference_velocity(np.stack([z_init[starts], z_init[starts + 1], z_init[starts + 2]]), dt)[0]
    P_w = None
    if P is not None and P.shape[1] > 0:
        P_s = timeseries.gaussian_smooth(P, cfg.sigma_pressure)
        P_w = np.stack([P_s[s : s + H] for s in starts])
    pred = rollout_zoh(model, q0, v0, dt, H, P_w)
    finite = np.isfinite(pred).all(axis=(1, 2))
    if not finite.any():
        return {"mse": float("inf"), "per_step": [], "sem": float("nan"), "starts": starts, "horizon": H, "n_finite": 0, "skip": skip}
    tgt = np.concatenate([frames[s : s + H] for s in starts[finite]])
    per = decode_mse(pred[finite].reshape(-1, pred.shape[-1]), tgt).reshape(-1, H)
    per_window = per.mean(1)
    sem = float(per_window.std(ddof=1) / math.sqrt(len(per_window))) if len(per_window) > 1 else float("nan")
    return {
        "mse": float(per.mean(0).mean()),
        "per_step": per.mean(0).tolist(),
        "sem": sem,
        "starts": starts,
        "horizon": H,
        "n_finite": int(finite.sum()),
        "skip": skip,
    }


def frequency_windows(
    q_enc: np.ndarray,
    P_raw: np.ndarray,
    P_smooth: np.ndarray,
    G: np.ndarray,
    model: Any,
    dt: float,
    cfg: KraussEvalConfig,
) -> dict[str, Any]:
    """Free-oscillation frequency of the encoded video and of the model, per window (§9.2).

    Args:
        q_enc: ``[n, d]`` smoothed whitened encodings (duplicates already trimmed).
        P_raw: ``[n, n_c]`` raw pressures (interval detection).
        P_smooth: ``[n, n_c]`` smoothed pressures (forcing, frozen at each window start).
        G: ``[d, d]`` ``G_bar`` scaled to trace ``d``, no ridge.
        model: the Lagrangian.
        dt: frame interval, s.
        cfg: protocol settings.

    Returns:
        Mapping with ``intervals`` (``[(a, b)]`` frame ranges), ``windows``
        (one dict per analysed window: ``start``, ``length``, ``f_enc_top``,
        ``f_sim_top``, ``f_enc_agg``, ``f_sim_agg``, ``amp_ratio``, ``status``
        = ``"ok" | "diverged" | "low_amplitude" | "flat"``), ``q_std``,
        ``diverge_norm``, and the means ``eps_freq`` (top mode, the cited
        number), ``eps_freq_agg``, ``f_enc_hz``, ``f_sim_hz`` over the ``ok``
        windows (NaN when there is none).
    """
    n = len(q_enc)
    lo = int(round(cfg.skip_s / dt))
    top = metrics.top_direction(G)
    q_std = metrics.g_rms_spread(q_enc, G)
    thr = cfg.diverge_factor * float(np.linalg.norm(q_enc, axis=1).max())
    min_len = int(round(cfg.min_flat_s / dt))
    intervals = flat_intervals(P_raw, lo, min_len, cfg.flat_step_tol, cfg.flat_total_tol, cfg.max_intervals) if lo < n else []
    windows: list[dict[str, Any]] = []
    for a, b in intervals:
        try:
            f0 = peak_frequency(q_enc[a:b], dt, G)
        except ValueError:
            windows.append({"start": a, "length": b - a, "status": "flat"})
            continue
        w = int(min(b - a, max(cfg.min_window, round(cfg.freq_window_periods / (f0 * dt)))))
        for st in range(a, b - w + 1, w):
            seg = q_enc[st : st + w]
            row: dict[str, Any] = {"start": st, "length": w, "interval": [a, b], "f0_interval_hz": f0}
            if metrics.g_rms_spread(seg, G) < cfg.min_amplitude * q_std or st + 2 >= n:
                windows.append({**row, "status": "low_amplitude"})
                continue
            v0 = timeseries.forward_difference_velocity(q_enc[st : st + 3], dt)[:1]
            P0 = None if P_smooth.shape[1] == 0 else P_smooth[st : st + 1]
            sim = rollout_zoh(model, q_enc[st : st + 1], v0, dt, w, P0)[0]
            if not np.isfinite(sim).all() or float(np.linalg.norm(sim, axis=1).max()) > thr:
                windows.append({**row, "status": "diverged"})
                continue
            try:
                row.update(
                    f_enc_top=peak_frequency(metrics.project(seg, top), dt),
                    f_sim_top=peak_frequency(metrics.project(sim, top), dt),
                    f_enc_agg=peak_frequency(seg, dt, G),
                    f_sim_agg=peak_frequency(sim, dt, G),
                    amp_ratio=metrics.g_rms_spread(sim, G) / max(metrics.g_rms_spread(seg, G), 1e-300),
                    status="ok",
                )
            except ValueError:  # the rollout came to rest: no peak above the cut
                row["status"] = "flat"
            windows.append(row)
    ok = [r for r in windows if r["status"] == "ok"]

    def mean(key_sim: str, key_enc: str) -> float:
        return float(np.mean([abs(r[key_sim] - r[key_enc]) / r[key_enc] for r in ok])) if ok else float("nan")

    return {
        "intervals": intervals,
        "windows": windows,
        "q_std": q_std,
        "diverge_norm": thr,
        "eps_freq": mean("f_sim_top", "f_enc_top"),
        "eps_freq_agg": mean("f_sim_agg", "f_enc_agg"),
        "f_enc_hz": float(np.mean([r["f_enc_top"] for r in ok])) if ok else float("nan"),
        "f_sim_hz": float(np.mean([r["f_sim_top"] for r in ok])) if ok else float("nan"),
    }
