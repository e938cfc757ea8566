"""The held-out gap before and after a refit, the chart-noise floor it is measured over, and the refit's energy check (paper §3.3, App. A.2; :mod:`lagsplat.diagnose.refit` fits the model)."""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from types import SimpleNamespace
from typing import Any

import numpy as np
import torch
from torch import nn

from lagsplat import metrics, timeseries
from lagsplat.diagnose.refit import GAP_METRICS
from lagsplat.diagnose.terms import (
    AugmentedLagrangian,
)
from lagsplat.dynamics.integrators import actuation_schedule, initial_state, rollout
from lagsplat.io.clip import HELD_OUT, TRAIN, ClipError

__all__ = ["energy_check", "envelope_decay", "noise_floor", "held_out_gap", "common_noise_floor", "gap_reduction"]


@torch.no_grad()
def energy_check(model: nn.Module, chart: Any, n_rollouts: int = 8, periods: float = 4.0, seed: int = 0) -> dict[str, Any]:
    """Numerical check of the energy bound of paper App. A.2 for a refit model.

    * ``max_dissipative_power``: the largest ``qdot^T f_k`` of each dissipative term
      over the training states (velocities by central differences) and the same
      states with velocities scaled by 0.1 and 10 (must be ``<= 0``);
    * without time-dependent terms or inputs, ``max_energy_rise``: the largest rise of
      ``E = T + V + V_eff`` along free rollouts of ``periods`` natural periods from
      ``n_rollouts`` training states, relative to the initial energy above the minimum
      reached (a few 1e-3 from the integrator at most when the bound holds).

    Args:
        model: a :class:`RefitModel` (a plain Lagrangian passes trivially).
        chart: the chart (training frames).
        n_rollouts, periods, seed: the free rollouts.

    Returns:
        ``{"dissipative_terms", "max_dissipative_power", "max_energy_rise", "holds"}``.
    """
    out: dict[str, Any] = {"dissipative_terms": [], "max_dissipative_power": None, "max_energy_rise": None}
    if not isinstance(model, AugmentedLagrangian):
        out["holds"] = True
        return out
    dt = float(np.median(np.diff(chart.t)))
    segs = [s for s in chart.segments(TRAIN) if len(s) > 3]
    q = np.concatenate([chart.q[s][1:-1] for s in segs])
    v = np.concatenate([(chart.q[s][2:] - chart.q[s][:-2]) / (2 * dt) for s in segs])
    Q = torch.as_tensor(q, dtype=torch.float32)
    worst = -float("inf")
    for term in model.terms:
        if term.kind != "dissipative":
            continue
        out["dissipative_terms"].append(type(term).__name__)
        for s in (0.1, 1.0, 10.0):
            Vt = torch.as_tensor(s * v, dtype=torch.float32)
            P = (Vt * term(Q, Vt, None)).sum(-1)
            worst = max(worst, float(P.max()))
    if out["dissipative_terms"]:
        out["max_dissipative_power"] = worst
    holds = worst <= 1e-6 if out["dissipative_terms"] else True
    if not model.time_channel and chart.n_u == 0:
        rng = np.random.default_rng(seed)
        idx = rng.choice(len(q), size=min(n_rollouts, len(q)), replace=False)
        try:
            f = timeseries.spectral_peak_frequency(metrics.project(chart.q[max(segs, key=len)], metrics.top_direction(chart.G_bar)), dt)
        except ValueError:
            f = 1.0 / (len(q) * dt)
        n = int(max(16, round(periods / (f * dt))))
        qs, vs = rollout(model, torch.as_tensor(q[idx], dtype=torch.float32), torch.as_tensor(v[idx], dtype=torch.float32), dt, n, fast=False)
        E = model.energy(qs.reshape(-1, chart.d), vs.reshape(-1, chart.d)).reshape(len(idx), n).double().numpy()
        if np.isfinite(E).all():
            q_rest = getattr(model.base, "q_rest", None)
            E_rest = float(model.potential(q_rest.detach()[None].float())[0]) if q_rest is not None else float(E.min())
            scale = np.maximum(E[:, 0] - min(E_rest, float(E.min())), 1e-12)
            run_min = np.minimum.accumulate(E, axis=1)
            rise = (E[:, 1:] - run_min[:, :-1]).max(1) / scale
            out["max_energy_rise"] = float(max(rise.max(), 0.0))
            holds = holds and out["max_energy_rise"] < 0.05
        else:
            out["max_energy_rise"] = float("inf")
            holds = False
    out["holds"] = bool(holds)
    return out


# ---------------------------------------------------------------------- held-out gap
def _envelope_at(c: np.ndarray, t: float, form: str) -> float:
    """The fitted envelope at ``t``; a linear one stops at zero (the motion has come to rest), so a decay is at most 100 %."""
    return max(0.0, float(c[0] + c[1] * t)) if form == "linear" else float(math.exp(c[0] + c[1] * t))


@torch.no_grad()
def envelope_decay(chart: Any, model: nn.Module, sigma: float = 1.0) -> dict[str, Any]:
    """Envelope decay of a free rollout over the longest held-out segment against the encoded one (module docstring).

    Args:
        chart: the chart (the model's: :func:`model_chart` for a refit model).
        model: the model.
        sigma: smoothing of the encoded trajectory, frames.

    Returns:
        ``{"form", "decay_encoded", "decay_model", "error", "n_half_cycles", "reliable"}``
        (``error`` ``None`` when fewer than 3 half cycles are found in either).
    """
    held = chart.segments(HELD_OUT)
    out: dict[str, Any] = {"form": None, "decay_encoded": None, "decay_model": None, "error": None, "n_half_cycles": 0, "reliable": False}
    if not held:
        return out
    ho = max(held, key=len)
    dt = float(np.median(np.diff(chart.t)))
    skip = timeseries.smoothing_edge(sigma)  # its edge replication would halve a mid-swing velocity
    q_s = timeseries.gaussian_smooth(chart.q[ho], sigma)[skip:]
    ho = ho[skip:]
    n = len(q_s)
    if n < 16:
        return out
    top = metrics.top_direction(chart.G_bar)
    p_enc = q_s @ top
    try:
        f = timeseries.spectral_peak_frequency(p_enc, dt)
    except ValueError:
        return out
    period = 1.0 / (f * dt)
    q0, v0 = initial_state(q_s, np.array([0]), dt)
    u = chart.u[ho]
    sim, _ = rollout(model, q0, v0, dt, n, u=actuation_schedule(u[None] if u.shape[1] else None, dt))
    p_sim = sim[0].double().numpy() @ top
    t = chart.t[ho] - chart.t[ho][0]
    te, ae = timeseries.half_cycle_amplitudes(p_enc, t, period)
    out["n_half_cycles"] = int(len(ae))
    if len(ae) < 3 or not np.isfinite(p_sim).all():
        return out
    ts, as_ = timeseries.half_cycle_amplitudes(p_sim, t, period)
    if len(as_) < 3 or np.any(ae <= 0) or np.any(as_ <= 0):
        return out
    fits = {form: timeseries.envelope_fit(te, ae, form) for form in ("linear", "exponential")}
    form = min(fits, key=lambda k: fits[k][1])
    c_e = fits[form][0]
    c_s, _ = timeseries.envelope_fit(ts, as_, form)
    t0, t1 = float(t[0]), float(t[-1])
    D_e = 1.0 - _envelope_at(c_e, t1, form) / max(_envelope_at(c_e, t0, form), 1e-12)
    D_s = 1.0 - _envelope_at(c_s, t1, form) / max(_envelope_at(c_s, t0, form), 1e-12)
    out.update(form=form, decay_encoded=D_e, decay_model=D_s, error=abs(D_s - D_e) / max(abs(D_e), 0.05), reliable=bool(abs(D_e) >= 0.05))
    return out


class _NullDecoder:
    """Stand-in autoencoder for a latent-only evaluation (renders one black pixel)."""

    height = width = 1

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        return torch.zeros(z.shape[0], 3, 1, 1)


def _evaluate_latent(chart: Any, model: nn.Module, cfg: Any, source: str) -> dict:
    """:func:`lagsplat.evaluate.evaluate` without frames (the image entries are meaningless)."""
    from lagsplat.evaluate import evaluate

    ch = copy.copy(chart)
    ch.ae_mse = np.ones(len(chart.t))
    clip_ = SimpleNamespace(images=np.zeros((len(chart.t), 1, 1, 3), np.uint8), meta={})
    return evaluate(clip_, _NullDecoder(), ch, model, cfg, source)


@torch.no_grad()
def noise_floor(chart: Any, model: nn.Module, eval_cfg: Any | None = None, n_draws: int = 8, seed: int = 0, source: str = "<clip>") -> dict[str, Any]:
    """``eps_q`` and ``eps_freq`` that a model with no gap would score on this chart (module docstring, "Chart-noise floor").

    Args:
        chart: the chart the model reads (:func:`model_chart` for a refit model).
        model: the model whose free motion stands in for the recording.
        eval_cfg: :class:`lagsplat.evaluate.EvalConfig` (default settings if ``None``).
        n_draws: Monte-Carlo draws of the noise.
        seed: seed of the noise draws.
        source: file name for error messages.

    Returns:
        ``{"eps_q", "eps_freq", "eps_q_sd", "eps_freq_sd", "noise" [d], "n_draws"}``: means and
        standard deviations over the draws, and the noise level per coordinate (whitened
        units); the means are ``None`` when the model's motion is not finite.

    Raises:
        lagsplat.io.clip.ClipError: if the chart has no held-out segment long enough (as :func:`lagsplat.evaluate.evaluate`).
        ValueError: if ``n_draws < 1``.
    """
    from lagsplat.diagnose.filters import chart_noise
    from lagsplat.evaluate import EvalConfig

    if int(n_draws) < 1:
        raise ValueError(f"noise_floor: n_draws must be >= 1, got {n_draws!r}")
    cfg = eval_cfg or EvalConfig()
    held = chart.segments(HELD_OUT)
    if not held:
        raise ClipError(f"{source}: the clip has no held-out frames to evaluate on")
    ho = max(held, key=len)
    n, e = len(ho), timeseries.smoothing_edge(cfg.sigma)
    if n < e + 5:
        raise ClipError(f"{source}: held-out segment has {n} frames, too short for a noise floor")
    dt = float(np.median(np.diff(chart.t)))
    noise = chart_noise([chart.q[s] for s in held])
    u = chart.u[ho]
    u = np.concatenate([u[e:], np.repeat(u[-1:], e, 0)]) if u.shape[1] else u  # the actuation the motion from frame e saw
    q0, v0 = initial_state(timeseries.gaussian_smooth(chart.q[ho], cfg.sigma), np.array([e]), dt)
    clean, _ = rollout(model, q0, v0, dt, n, u=actuation_schedule(u[None] if u.shape[1] else None, dt))
    clean = clean[0].double().numpy()
    out: dict[str, Any] = {"eps_q": None, "eps_freq": None, "eps_q_sd": None, "eps_freq_sd": None, "noise": noise.tolist(), "n_draws": int(n_draws)}
    if not np.isfinite(clean).all():
        return out
    rng = np.random.default_rng(seed)
    ch = copy.copy(chart)
    ch.u = chart.u.copy()
    ch.u[ho] = u
    draws = []
    for _ in range(int(n_draws)):
        ch.q = chart.q.copy()
        ch.q[ho] = clean + rng.standard_normal(clean.shape) * noise
        m = _evaluate_latent(ch, model, cfg, source)
        if m["eps_q"]["value"] is None or m["eps_freq"]["value"] is None:  # the clean motion is at rest: no floor to read
            return out
        draws.append((m["eps_q"]["value"], m["eps_freq"]["value"]))
    a = np.array(draws)
    out.update(eps_q=float(a[:, 0].mean()), eps_freq=float(a[:, 1].mean()), eps_q_sd=float(a[:, 0].std()), eps_freq_sd=float(a[:, 1].std()))
    return out


def held_out_gap(
    chart: Any, model: nn.Module, clip: Any | None = None, ae: Any | None = None, eval_cfg: Any | None = None, source: str = "<clip>",
    floor_draws: int = 8,
) -> dict[str, Any]:  # fmt: skip
    """The gap of a model on the held-out frames (module docstring).

    Args:
        chart: the chart the model reads (:func:`model_chart` for a refit model).
        model: the model (``acceleration``; ``modal_analysis`` for the evaluation record).
        clip, ae: the clip and autoencoder for the image error; both ``None``: latent numbers only.
        eval_cfg: :class:`lagsplat.evaluate.EvalConfig` (default settings if ``None``).
        source: file name for error messages.
        floor_draws: Monte-Carlo draws of :func:`noise_floor` (0: no floor, the
            ``*_over_floor`` entries are ``None``).

    Returns:
        ``{"eps_q", "eps_freq", "eps_I", "eps_AE", "image_excess", "envelope_decay_error",
        "envelope": {...}, "f_sim_hz", "f_enc_hz", "n_diverged", "floor": {...}, "floor_common",
        "eps_q_over_floor", "eps_freq_over_floor"}`` (image entries ``None`` without frames; the
        over-floor entries over this model's own floor, :func:`common_noise_floor` to compare gaps).

    Raises:
        lagsplat.io.clip.ClipError: if the held-out segment is too short (see :func:`lagsplat.evaluate.evaluate`).
    """
    from lagsplat.evaluate import EvalConfig, evaluate

    cfg = eval_cfg or EvalConfig()
    latent_only = clip is None or ae is None
    m = _evaluate_latent(chart, model, cfg, source) if latent_only else evaluate(clip, ae, chart, model, cfg, source)
    env = envelope_decay(chart, model, cfg.sigma)
    v = {k: e["value"] for k, e in m.items()}
    eps_I = None if latent_only else v["eps_I"]
    eps_AE = None if latent_only else v["eps_AE"]
    floor = noise_floor(chart, model, cfg, floor_draws, source=source) if floor_draws > 0 else None
    gap = {
        "eps_q": v["eps_q"], "eps_freq": v["eps_freq"], "eps_I": eps_I, "eps_AE": eps_AE,
        "image_excess": None if latent_only else (eps_I - eps_AE) / max(eps_AE, 1e-300),
        "envelope_decay_error": env["error"], "envelope": env, "f_sim_hz": v["f_sim_hz"], "f_enc_hz": v["f_enc_hz"],
        "n_diverged": v["n_diverged"], "horizon": m["eps_q"]["horizon"], "floor": floor,
    }  # fmt: skip
    return common_noise_floor(gap)[0]  # over its own floor until compared with another gap


def common_noise_floor(*gaps: Mapping[str, Any] | None) -> list[dict[str, Any] | None]:
    """The gaps of :func:`held_out_gap` with ``eps_q_over_floor`` and ``eps_freq_over_floor`` over one floor.

    The floor of each metric is the lowest :func:`noise_floor` among the gaps
    (module docstring); it is recorded as ``floor_common``. Gaps given as ``None``
    stay ``None``; a metric whose floor is missing in every gap keeps ``None``.

    Returns:
        New dicts, in the order given.
    """
    common = {}
    for k in ("eps_q", "eps_freq"):
        vals = [g["floor"][k] for g in gaps if g is not None and g.get("floor") and g["floor"].get(k) is not None]
        common[k] = min(vals) if vals else None
    return [
        None if g is None else dict(g, floor_common=common, **{
            f"{k}_over_floor": None if common[k] is None or g.get(k) is None else g[k] - common[k] for k in common
        })  # fmt: skip
        for g in gaps
    ]


def gap_reduction(before: Mapping[str, Any], after: Mapping[str, Any]) -> dict[str, float | None]:
    """``1 - after / before`` for each of :data:`GAP_METRICS` (positive: the gap shrank; ``None`` if undefined)."""
    out: dict[str, float | None] = {}
    for k in GAP_METRICS:
        b, a = before.get(k), after.get(k)
        if b is None or a is None or not (math.isfinite(b) and math.isfinite(a)) or b <= 0:
            out[k] = None
        else:
            out[k] = float(1.0 - a / b)
    return out
