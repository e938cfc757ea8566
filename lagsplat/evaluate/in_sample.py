"""A clip identified on all its frames: what its ``metrics.json`` can say without held-out frames.

A recording with between about 2 and 6 periods of motion is too short for the
held-out protocol of paper §4.1 (three periods held out and as many again to
train); the preparation then keeps every frame for training and marks the clip
(``meta["split"]["no_held_out"]``, :attr:`lagsplat.io.clip.Clip.no_held_out`,
e.g. ``"no held-out validation (2.4 periods)"``). Stage 2 trains on all of it,
and :func:`evaluate_in_sample` reads, on the same frames the model was fitted to:

* ``f_enc_hz``, ``zeta_enc``: the encoded video's frequency (spectral peak of the
  projection on ``G_bar``'s most visible direction, as ``eps_freq``) and damping
  ratio (exponential envelope of its half-cycle amplitudes) over the longest
  training segment;
* ``f_sim_hz``, ``zeta_sim``: the same of one free rollout of the model from the
  encoded state past the smoothing's edge, through the whole segment;
* ``eps_freq_in_sample``: ``|f_sim - f_enc| / f_enc``, the paper's frequency error
  read in-sample (its own key: ``eps_freq`` keeps its held-out meaning);
* the model's linearised modes (:func:`lagsplat.evaluate.paper.modal_metrics`).

The paper's held-out metrics (``eps_freq``, ``eps_q``, ``eps_I``, ``eps_AE``,
``eps_I_over_AE``, ``f_enc_segment_hz``) are ``None``, their definition the clip's note.
"""

from __future__ import annotations

import math

import numpy as np

from lagsplat import metrics, timeseries
from lagsplat.chart import Chart
from lagsplat.dynamics.integrators import actuation_schedule, initial_state, rollout
from lagsplat.evaluate.common import metric_entry
from lagsplat.evaluate.paper import EvalConfig, modal_metrics
from lagsplat.io.clip import TRAIN, Clip, ClipError
from lagsplat.models.autoencoder import AutoEncoder
from lagsplat.models.lagrangian import Lagrangian

__all__ = ["HELD_OUT_METRICS", "ENVELOPE", "damping_ratio", "free_rollout_projection", "evaluate_in_sample"]

#: The held-out metrics of paper §4.1 that a clip without held-out frames cannot give (``value`` None).
HELD_OUT_METRICS = ("eps_freq", "eps_q", "eps_I", "eps_AE", "eps_I_over_AE", "f_enc_segment_hz")


#: How every damping ratio of the evaluation is read (:func:`damping_ratio`), as ``metrics.json`` defines it.
ENVELOPE = "exponential envelope of the half-cycle amplitudes of the projection on G_bar's top eigenvector, s / sqrt(s^2 + (2 pi f)^2)"


def free_rollout_projection(model: Lagrangian, q_s: np.ndarray, u: np.ndarray, dt: float, top: np.ndarray, lo: int) -> np.ndarray | None:
    """One free rollout of ``model`` from the state of the smoothed segment ``q_s [n, d]`` at frame ``lo`` through its
    end, driven by the segment's actuation ``u [n, n_u]`` (``n_u`` may be 0), projected on ``top [d]``: ``[n - lo]``,
    or ``None`` when it diverges."""
    q0, v0 = initial_state(q_s, np.array([lo]), dt)
    sim, _ = rollout(model, q0, v0, dt, len(q_s) - lo, u=actuation_schedule(u[lo:][None], dt))
    sim = sim[0].numpy()
    return metrics.project(sim, top) if np.isfinite(sim).all() else None


def damping_ratio(p: np.ndarray, dt: float, f_hz: float) -> float | None:
    """Damping ratio of a decaying oscillation ``p [n]`` sampled every ``dt`` s, oscillating at ``f_hz``.

    The half-cycle amplitudes (:func:`lagsplat.timeseries.half_cycle_amplitudes`) are fitted with
    an exponential envelope (:func:`lagsplat.timeseries.envelope_fit`), decay rate ``s`` (1/s);
    ``zeta = s / sqrt(s^2 + (2 pi f)^2)`` (viscous damping: ``s = zeta omega_n``, ``2 pi f`` the
    damped angular frequency). Negative for a growing oscillation.

    Returns:
        The ratio (dimensionless), or ``None`` with fewer than 3 half cycles, a non-positive
        amplitude, a non-finite trajectory or frequency.
    """
    if not (np.isfinite(p).all() and math.isfinite(f_hz) and f_hz > 0):
        return None
    t = np.arange(len(p)) * float(dt)
    tk, amp = timeseries.half_cycle_amplitudes(np.asarray(p, float), t, 1.0 / (f_hz * dt))
    if len(amp) < 3 or np.any(amp <= 0):
        return None
    c, _ = timeseries.envelope_fit(tk, amp, "exponential")
    s, w = -float(c[1]), 2.0 * math.pi * float(f_hz)
    return s / math.sqrt(s * s + w * w)


def evaluate_in_sample(clip: Clip, ae: AutoEncoder, chart: Chart, model: Lagrangian, cfg: EvalConfig, note: str, source: str = "<clip>") -> dict:
    """The ``metrics`` block of a clip identified on all its frames (module docstring).

    Args:
        clip: the clip (its known physics in ``meta``; frames are not read).
        ae: the frozen autoencoder (not read; the protocols' common signature).
        chart: its chart, ``q [T, d]`` whitened, every frame training.
        model: the trained Lagrangian.
        cfg: settings (``sigma`` the latents' smoothing, frames).
        note: the clip's ``no_held_out`` note, e.g. ``"no held-out validation (2.4 periods)"``.
        source: file name for error messages.

    Returns:
        name -> ``{value, definition, horizon, units}`` (:func:`~lagsplat.evaluate.common.metric_entry`).

    Raises:
        ClipError: if the longest training segment has fewer than 16 frames (no frequency to read).
    """
    dt = float(np.median(np.diff(chart.t)))
    G = metrics.normalise_trace(chart.G_bar)
    top = metrics.top_direction(G)
    segs = chart.segments(TRAIN)
    seg = max(segs, key=len) if segs else np.zeros(0, int)
    n = len(seg)
    lo = metrics.rollout_start(cfg.sigma, n, 16)  # past the smoothing's edge, as every rollout of the evaluation
    if n - lo < 16:
        raise ClipError(f"{source}: the training segment has {n} frames, too short to measure a frequency ({note})")
    q_s = timeseries.gaussian_smooth(chart.q[seg], cfg.sigma)
    p_enc = metrics.project(q_s[lo:], top)
    f_enc = float(timeseries.spectral_peak_frequency(p_enc, dt))
    p_sim = free_rollout_projection(model, q_s, chart.u[seg], dt, top, lo)
    finite = p_sim is not None
    f_sim = float(timeseries.spectral_peak_frequency(p_sim, dt)) if finite else float("nan")
    span = f"in-sample: the {n - lo} training frames from frame {lo} ({(n - lo) * dt:.2f} s, {(n - lo) * dt * f_enc:.1f} periods)"
    why = f"not measured: {note}; the held-out protocol (paper §4.1) needs held-out frames (see eps_freq_in_sample)"
    out = {k: metric_entry(None, why, "") for k in HELD_OUT_METRICS}
    proj = "spectral peak (Hann, log-parabolic) of the projection on G_bar's top eigenvector"
    env = ENVELOPE
    out.update(
        f_enc_hz=metric_entry(f_enc, f"frequency of the encoded video over the whole clip (in-sample); {proj}", span, "Hz"),
        f_sim_hz=metric_entry(f_sim, f"frequency of the model's free rollout from the encoded state, through the whole clip (in-sample); {proj}", span, "Hz"),
        eps_freq_in_sample=metric_entry(
            abs(f_sim - f_enc) / f_enc if finite else float("nan"),
            "|f_sim - f_enc| / f_enc on the frames the model was fitted to: eps_freq (paper §4.1) read in-sample, one window over the clip; "
            "not a held-out validation", span, "fraction"),
        zeta_enc=metric_entry(damping_ratio(p_enc, dt, f_enc), f"damping ratio of the encoded video over the whole clip (in-sample); {env}", span, "1"),
        zeta_sim=metric_entry(damping_ratio(p_sim, dt, f_sim) if finite else None, f"damping ratio of the model's free rollout (in-sample); {env}", span, "1"),
        n_diverged=metric_entry(int(not finite), "free rollouts that became non-finite", span, "count"),
    )  # fmt: skip
    if "continuity_jump_ratio" in chart.meta:
        out["chart_jump_ratio"] = metric_entry(
            chart.meta["continuity_jump_ratio"], "max |second difference| / median |first difference| of the encoded trajectory on G_bar's top "
            "direction (lagsplat.chart.chart_continuity)", "all frames", "ratio")  # fmt: skip
    out.update(modal_metrics(clip, chart, model))
    return out
