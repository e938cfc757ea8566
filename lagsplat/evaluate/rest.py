"""Held-out frames at rest: a motion that stopped before the held-out part (dry friction does this).

A free decay under dry friction ends at rest, often off the centre of the
swing, and a clip split by time (paper §4.1) can then hold out only still
frames, or frames that stop moving well before two periods. The held-out
frequency and the NRMSE over the held-out spread are then noise over noise (an
NRMSE in the hundreds) or shorter than their horizon. :func:`held_out_rest` detects
the case; :func:`rest_metrics` scores what the still frames show instead:
when and where the object came to rest, and whether the model, run free from
the last training state through the held-out frames, comes to rest there too.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from lagsplat import metrics, timeseries
from lagsplat.dynamics.integrators import actuation_schedule, initial_state, rollout
from lagsplat.evaluate.common import decode_mse, metric_entry
from lagsplat.io.clip import HELD_OUT, TRAIN

__all__ = ["REST_SHARE", "MOVING_SHARE", "held_out_rest", "rest_metrics"]

#: The held-out frames are at rest when their G-RMS spread is below this share of the training frames'.
REST_SHARE = 0.05
#: A frame still moves when it lies farther than this share of the training spread from the rest position.
MOVING_SHARE = 0.2

#: The entries of the oscillation metrics that a still held-out part cannot give (``value`` None).
NOT_MEASURED = ("eps_freq", "f_sim_hz", "f_enc_hz", "f_enc_segment_hz", "eps_q")


def _dev(q: np.ndarray, rest: np.ndarray, G: np.ndarray) -> np.ndarray:
    """G-norm of ``q [n,d] - rest [d]`` per frame."""
    e = q - rest
    return np.sqrt(np.maximum(np.einsum("ni,ij,nj->n", e, G, e), 0.0))


def _settle_index(dev: np.ndarray, tol: float) -> int | None:
    """First index after which ``dev`` stays within ``tol`` (``None``: it never settles; 0: it starts settled)."""
    out = np.flatnonzero(dev > tol)
    if not len(out):
        return 0
    return None if out[-1] == len(dev) - 1 else int(out[-1] + 1)


def held_out_rest(chart: Any, G: np.ndarray, sigma: float, n_periods: float = 2.0) -> dict[str, Any] | None:
    """Whether the encoded motion is at rest on the longest held-out segment, and since when.

    Two cases count as at rest: the whole held-out segment is still, or the motion comes to
    rest inside it (its last third is still) after fewer moving frames than ``n_periods``
    periods of the training motion (plus the 3 frames an initial state needs), too few for
    the oscillation metrics' horizon (paper §4.1).

    Args:
        chart: the chart (``q [T,d]``, ``t``, ``split``, ``episode``).
        G: ``[d,d]`` metric (``G_bar`` normalised to trace ``d``).
        sigma: smoothing of the latents, frames (as the evaluation).
        n_periods: the oscillation metrics' horizon in periods of the training motion.

    Returns:
        ``None`` when the held-out frames move (G-RMS spread at least :data:`REST_SHARE` of the
        training frames'); otherwise ``{"rest_position" [d] (whitened), "rest_time_s" (s from the
        start of the take, when the motion last left the :data:`MOVING_SHARE` band about the
        rest position), "spread_train", "held_out" (frame indices), "train_before" (the training
        segment just before, or None), "rest_from" (index into ``held_out`` of its first frame at
        rest)}``.
    """
    held, train = chart.segments(HELD_OUT), chart.segments(TRAIN)
    if not held or not train:
        return None
    ho = max(held, key=len)
    s_tr = metrics.g_rms_spread(np.concatenate([timeseries.gaussian_smooth(chart.q[s], sigma) for s in train]), G)
    q_ho = timeseries.gaussian_smooth(chart.q[ho], sigma)
    if s_tr <= 0:
        return None
    rest_from = 0
    if metrics.g_rms_spread(q_ho, G) >= REST_SHARE * s_tr:
        rest_from = _stops_inside(chart, train, q_ho, G, s_tr, sigma, n_periods)
        if rest_from is None:
            return None
    rest = q_ho[rest_from:].mean(0)
    take = np.flatnonzero(chart.episode == chart.episode[ho[0]])
    take = take[take <= ho[-1]]
    q_take = timeseries.gaussian_smooth(chart.q[take], sigma)
    k = _settle_index(_dev(q_take, rest, G), MOVING_SHARE * s_tr)
    before = [s for s in train if s[-1] + 1 == ho[0]]
    return {"rest_position": rest, "rest_time_s": float(chart.t[take[k or 0]] - chart.t[take[0]]), "spread_train": s_tr, "held_out": ho,
            "train_before": before[0] if before else None, "rest_from": rest_from}  # fmt: skip


def _stops_inside(chart: Any, train: list, q_ho: np.ndarray, G: np.ndarray, s_tr: float, sigma: float, n_periods: float) -> int | None:
    """Index into the held-out segment where a motion that stops inside it comes to rest, or ``None``.

    ``None`` unless the segment's last third is still (G-RMS spread below :data:`REST_SHARE` of the
    training spread) and the frames before the rest are fewer than ``n_periods`` periods of the
    training motion plus 3 (:func:`held_out_rest`).
    """
    tail = q_ho[2 * len(q_ho) // 3 :]
    if len(tail) < 3 or metrics.g_rms_spread(tail, G) >= REST_SHARE * s_tr:
        return None
    k = _settle_index(_dev(q_ho, tail.mean(0), G), MOVING_SHARE * s_tr)
    if k is None:
        return None
    dt = float(np.median(np.diff(chart.t)))
    longest = max(train, key=len)
    q_tr = timeseries.gaussian_smooth(chart.q[longest], sigma)
    f_tr = timeseries.spectral_peak_frequency(metrics.project(q_tr, metrics.top_direction(G)), dt)
    horizon = int(round(n_periods / (f_tr * dt))) + 3 if f_tr > 0 else len(q_ho)
    return k if k < horizon else None


def rest_metrics(clip: Any, ae: Any, chart: Any, model: Any, cfg: Any, G: np.ndarray, rest: dict[str, Any]) -> dict[str, dict]:
    """The held-out metrics of a motion at rest (module docstring); ``metrics.json`` entries.

    The model runs free from the last training state (the smoothed state three frames before
    the held-out segment; from the segment's first frame when no training segment precedes
    it) through the held-out frames. Entries: ``held_out_at_rest`` (1), ``rest_time_s``,
    ``rest_position``, ``model_rest_time_s`` (``None``: still moving at the end),
    ``eps_rest`` (G-RMS distance of the model from the observed rest over the held-out
    frames, in units of the training spread; 0 = it rests there), ``eps_I``, ``eps_AE``,
    ``eps_I_over_AE``, ``n_diverged``, and the oscillation metrics with value ``None``.
    """
    dt = float(np.median(np.diff(chart.t)))
    ho, pre, s_tr, pos = rest["held_out"], rest["train_before"], rest["spread_train"], rest["rest_position"]
    lead = 0
    if pre is not None and len(pre) >= 3:
        q_pre = timeseries.gaussian_smooth(chart.q[pre], cfg.sigma)
        q0, v0 = initial_state(q_pre, np.array([len(pre) - 3]), dt)
        lead = 3
    else:
        q0, v0 = initial_state(timeseries.gaussian_smooth(chart.q[ho], cfg.sigma), np.array([0]), dt)
    u = np.concatenate([chart.u[pre[-lead:]], chart.u[ho]]) if lead else chart.u[ho]
    sim, _ = rollout(model, q0, v0, dt, lead + len(ho), u=actuation_schedule(u[None] if u.shape[1] else None, dt))
    sim = sim[0].numpy()[lead:]
    finite = bool(np.isfinite(sim).all())
    at_rest = rest.get("rest_from", 0)
    dev = _dev(sim[at_rest:], pos, G) if finite else np.full(len(ho) - at_rest, np.inf)
    settle = _settle_index(_dev(sim, sim[-1], G), MOVING_SHARE * s_tr) if finite else None
    t0 = float(chart.t[np.flatnonzero(chart.episode == chart.episode[ho[0]])[0]])
    eps_I = float(decode_mse(ae, chart, sim, clip.images[ho], cfg.render_batch).mean()) if finite else float("inf")
    eps_AE = float(chart.ae_mse[ho].mean())
    horizon = f"the {len(ho)} held-out frames ({len(ho) * dt:.2f} s), one free rollout from the last training state"
    why = "not measured: the object is at rest in the held-out frames (held_out_at_rest; see eps_rest)"
    out = {k: metric_entry(None, why, horizon) for k in NOT_MEASURED}
    out.update(
        held_out_at_rest=metric_entry(1, f"the held-out frames' G-RMS spread is below {REST_SHARE:g} of the training frames', or they come to rest within {cfg.n_periods:g} periods", horizon, "flag"),
        rest_time_s=metric_entry(rest["rest_time_s"], f"when the encoded motion last left a band of {MOVING_SHARE:g} training spreads about its rest position, from the start of the take", "", "s"),
        rest_position=metric_entry(np.asarray(pos, float).tolist(), "mean encoded state of the held-out frames at rest (whitened chart)", horizon, "whitened q"),
        model_rest_time_s=metric_entry(None if settle is None else float(chart.t[ho[settle]] - t0), "when the model's free rollout settles within the same band about its final state (None: still moving)", horizon, "s"),
        eps_rest=metric_entry(float(np.sqrt(np.mean(dev**2)) / s_tr), f"G-RMS distance of the model's free rollout from the observed rest position over the {len(ho) - at_rest} held-out frames at rest / G-RMS spread of the training frames", horizon, "0 = rests where the object rests"),
        eps_I=metric_entry(eps_I, "image MSE of decode(q_sim) against the real frames, pixels in [0,1], training resolution", horizon, "MSE"),
        eps_AE=metric_entry(eps_AE, "autoencoder floor: MSE of decode(encode(frame)) on held-out frames", f"{len(ho)} held-out frames", "MSE"),
        eps_I_over_AE=metric_entry(eps_I / eps_AE, "eps_I / eps_AE", horizon, "ratio"),
        n_diverged=metric_entry(int(not finite), "rollouts that became non-finite", horizon, "count"),
    )  # fmt: skip
    return out
