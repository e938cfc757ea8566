"""Evaluation of an identified model on the held-out frames (paper §4.1 "Metrics").

Produces ``metrics.json``: every number a table or figure needs, each stored
with its definition and horizon, so tables never recompute anything.

Protocol (held-out segment, latents whitened and smoothed with a Gaussian of
``sigma`` frames as in training; initial velocity by the second-order forward
difference, as the reference code does):

* ``eps_freq``: the free-oscillation frequency of a rollout against the one
  the encoded video shows, both from :func:`lagsplat.timeseries.spectral_peak_frequency`
  on the projection onto the most visible direction of ``G_bar``. The
  held-out segment is tiled by windows of ``min(n, max(16, 8 periods))``
  frames; from each window start the model runs free for the window length.
* ``eps_q``: latent NRMSE in ``G_bar`` (trace ``d``) over two natural periods of
  the encoded video, from ``n_windows`` seeded starts drawn with replacement.
* ``eps_I``: image MSE of the decoded rollouts against the real frames on the
  same windows and steps; ``eps_AE`` the autoencoder floor on held-out frames;
  the table reports ``eps_I / eps_AE``.

No rollout starts within :func:`lagsplat.timeseries.smoothing_edge` frames of the
segment's first frame (4 at ``sigma = 1``; fewer only if the segment is too
short for it): the smoothing replicates that frame backwards, so a velocity
read there is biased low (about half at a mid-swing start). A linear model's
frequency does not care, but one whose frequency depends on the amplitude (an
end stop) then runs at the wrong one. The reference protocol never starts
there either: it skips the recording's first 8 s (the reference code).
"""

from __future__ import annotations


import numpy as np

from lagsplat import metrics, timeseries
from lagsplat.chart import Chart
from lagsplat.dynamics.integrators import actuation_schedule, initial_state, rollout
from lagsplat.io.clip import HELD_OUT, Clip, ClipError
from lagsplat.models.lagrangian import Lagrangian
from lagsplat.models.autoencoder import AutoEncoder
from lagsplat.evaluate.common import decoded_image_errors, metric_entry
from lagsplat.evaluate.rest import held_out_rest, rest_metrics
from lagsplat.evaluate.settings import EvalConfig

__all__ = ["EvalConfig", "evaluate", "frequency_windows", "modal_metrics"]




def evaluate(clip: Clip, ae: AutoEncoder, chart: Chart, model: Lagrangian, cfg: EvalConfig, source: str = "<clip>") -> dict:
    """Score a trained model on the clip's held-out frames.

    Args:
        clip: the ingested clip (frames for the image error, known physics in ``meta``).
        ae: the frozen autoencoder.
        chart: its chart.
        model: the trained Lagrangian.
        cfg: settings.
        source: file name for error messages.

    Returns:
        The ``metrics`` mapping of ``metrics.json`` (name -> entry with value,
        definition, horizon, units).

    When the object is at rest in the held-out frames (a motion stopped by dry
    friction), the oscillation metrics are ``None`` and the rest is scored instead
    (:mod:`lagsplat.evaluate.rest`: ``held_out_at_rest``, ``rest_time_s``, ``eps_rest``).
    A clip identified on all its frames (:attr:`Clip.no_held_out <lagsplat.io.clip.Clip.no_held_out>`)
    is read in-sample instead (:func:`lagsplat.evaluate.in_sample.evaluate_in_sample`): the
    held-out metrics are ``None`` with the clip's note.

    Raises:
        ClipError: if the clip has no held-out frames and no ``no_held_out`` note, or the
            held-out segment is shorter than two natural periods (plus the 3 frames the
            initial state needs).
    """
    dt = float(np.median(np.diff(chart.t)))
    G = metrics.normalise_trace(chart.G_bar)
    top = metrics.top_direction(G)
    held = chart.segments(HELD_OUT)
    if not held and clip.no_held_out is not None:  # identified on all its frames: read in-sample
        from lagsplat.evaluate.in_sample import evaluate_in_sample

        return evaluate_in_sample(clip, ae, chart, model, cfg, clip.no_held_out, source)
    if not held:
        raise ClipError(f"{source}: the clip has no held-out frames to evaluate on")
    ho = max(held, key=len)
    q_s = timeseries.gaussian_smooth(chart.q[ho], cfg.sigma)
    u_ho = chart.u[ho]  # measured actuation drives every rollout (paper Eq. 6); [n, 0] if none
    n = len(q_s)
    rest = held_out_rest(chart, G, cfg.sigma, cfg.n_periods)
    if rest is not None:  # the motion stopped before or early in the held-out part: too little oscillates there to score
        return {**rest_metrics(clip, ae, chart, model, cfg, G, rest), **modal_metrics(clip, chart, model)}
    if n < 16:
        raise ClipError(f"{source}: held-out segment has {n} frames, too short to measure a frequency")
    f_enc = timeseries.spectral_peak_frequency(metrics.project(q_s, top), dt)
    period = 1.0 / (f_enc * dt)  # frames
    H = int(round(cfg.n_periods * period))
    if n < H + 3:
        raise ClipError(
            f"{source}: held-out segment has {n} frames ({n * dt:.2f} s) but two natural periods need {H + 3} "
            f"({(H + 3) * dt:.2f} s at {f_enc:.3f} Hz); lower split.train_fraction or use a longer clip"
        )
    q_std = metrics.g_rms_spread(q_s, G)
    f_enc_w, f_sim_w, w = frequency_windows(model, q_s, u_ho, dt, top, G, period, cfg)
    eps_freq = float(np.mean(np.abs(f_sim_w - f_enc_w) / f_enc_w))

    # ---- latent NRMSE and image error over two periods
    starts = metrics.window_starts(metrics.rollout_start(cfg.sigma, n, H + 3), n - H - 2, cfg.n_windows, cfg.seed)
    q0, v0 = initial_state(q_s, starts, dt)
    u_w = np.stack([u_ho[s : s + H] for s in starts])
    pred, _ = rollout(model, q0, v0, dt, H, u=actuation_schedule(u_w, dt))
    pred = pred.numpy()
    true = np.stack([q_s[s : s + H] for s in starts])
    finite = np.isfinite(pred).all(axis=(1, 2))
    eps_q = metrics.latent_nrmse(pred[finite], true[finite], G, q_std) if finite.any() else float("inf")
    frames = np.concatenate([clip.images[ho[s : s + H]] for s in starts[finite]])
    mse, psnr, ssim = decoded_image_errors(ae, chart, pred[finite].reshape(-1, chart.d), frames, cfg.render_batch)
    eps_I = float(mse.mean())
    eps_AE = float(chart.ae_mse[ho].mean())

    horizon = f"{cfg.n_periods:g} natural periods = {H} frames = {H * dt:.3f} s, {int(finite.sum())}/{len(starts)} windows (seed {cfg.seed})"
    out: dict[str, dict] = {
        "eps_freq": metric_entry(eps_freq, "mean over windows of |f_sim - f_enc| / f_enc; spectral peak (Hann, log-parabolic) of the projection on G_bar's top eigenvector; free rollout from each window start", f"{len(f_enc_w)} window(s) of {w} frames = {w * dt:.2f} s", "fraction"),
        "f_sim_hz": metric_entry(float(np.nanmean(f_sim_w)), "frequency of the free rollouts (mean over frequency windows)", f"{w * dt:.2f} s", "Hz"),
        "f_enc_hz": metric_entry(float(np.mean(f_enc_w)), "frequency of the encoded held-out video (mean over frequency windows)", f"{w * dt:.2f} s", "Hz"),
        "f_enc_segment_hz": metric_entry(f_enc, "frequency of the whole encoded held-out segment; sets the two-period horizon", f"{n * dt:.2f} s", "Hz"),
        "eps_q": metric_entry(eps_q, "latent NRMSE: sqrt(mean |q_sim - q_enc|^2_G) / G-RMS spread of q_enc, G = G_bar normalised to trace d", horizon, "1 = predicting the mean"),
        "eps_I": metric_entry(eps_I, "image MSE of decode(q_sim) against the real frames, pixels in [0,1], training resolution", horizon, "MSE"),
        "eps_AE": metric_entry(eps_AE, "autoencoder floor: MSE of decode(encode(frame)) on held-out frames", f"{n} held-out frames", "MSE"),
        "eps_I_over_AE": metric_entry(eps_I / eps_AE, "eps_I / eps_AE", horizon, "ratio"),
        "n_diverged": metric_entry(int((~finite).sum()), "rollouts that became non-finite (excluded, counted here)", horizon, "count"),
    }
    if "continuity_jump_ratio" in chart.meta:
        out["chart_jump_ratio"] = metric_entry(
            chart.meta["continuity_jump_ratio"],
            "max |second difference| / median |first difference| of the encoded trajectory on G_bar's top direction; "
            "well below 1 for a smooth chart, >= 5 flags a folded or torn chart (lagsplat.chart.chart_continuity)",
            "all frames",
            "ratio",
        )
    out.update(held_out_damping(model, q_s, u_ho, dt, top, cfg, f_enc))
    out.update(modal_metrics(clip, chart, model))
    if "f_observed_hz" in clip.meta.get("truth", {}):
        f_true = float(clip.meta["truth"]["f_observed_hz"])
        out["f_truth_hz"] = metric_entry(f_true, "generator's true frequency on the held-out segment (lagsplat.synth)", "", "Hz")
        out["eps_freq_truth"] = metric_entry(abs(np.nanmean(f_sim_w) - f_true) / f_true, "|f_sim - f_truth| / f_truth", "", "fraction")
    # the image-quality numbers the field reports beside the MSE ratio, on the same rollout windows (scikit-image)
    fin = np.isfinite(psnr)
    out["psnr_db"] = metric_entry(
        float(psnr[fin].mean()) if fin.any() else float("nan"),
        "PSNR of decode(q_sim) against the real frames, pixels in [0,1] (skimage.metrics.peak_signal_noise_ratio), mean over states",
        horizon,
        "dB",
    )
    out["ssim"] = metric_entry(
        float(np.nanmean(ssim)) if np.isfinite(ssim).any() else float("nan"),
        "SSIM of decode(q_sim) against the real frames (skimage.metrics.structural_similarity, 7 x 7 window, channel mean), mean over states",
        horizon,
        "1 = identical",
    )
    return out


def frequency_windows(
    model: Lagrangian, q_s: np.ndarray, u: np.ndarray, dt: float, top: np.ndarray, G: np.ndarray, period: float, cfg: EvalConfig
) -> tuple[np.ndarray, np.ndarray, int]:
    """The windowed frequency comparison behind ``eps_freq`` (paper §4.1; module docstring).

    The segment is tiled by windows of ``min(n - lo, max(16, freq_window_periods * period))``
    frames from ``lo`` (:func:`lagsplat.metrics.rollout_start`, past the smoothing's edge);
    windows whose G-RMS spread is below ``min_amplitude`` of the segment's are skipped; from
    each window start the model runs free for the window length, driven by the measured
    actuation, and both frequencies are the spectral peak of the projection on ``top``.

    Args:
        model: the Lagrangian.
        q_s: ``[n, d]`` smoothed encoded segment (whitened chart).
        u: ``[n, n_u]`` its actuation (``n_u`` may be 0).
        dt: frame interval, s.
        top: ``[d]`` G_bar's most visible direction.
        G: ``[d, d]`` trace-normalised G_bar.
        period: the encoded motion's period, frames.
        cfg: settings (``sigma``, ``freq_window_periods``, ``min_amplitude``).

    Returns:
        ``(f_enc [m], f_sim [m], w)``: per window the encoded and the simulated frequency (Hz;
        ``nan`` for a rollout that diverged) and the window length in frames.
    """
    n = len(q_s)
    q_std = metrics.g_rms_spread(q_s, G)
    lo = metrics.rollout_start(cfg.sigma, n, 16)  # past the smoothing's edge (module docstring)
    w = int(min(n - lo, max(16, round(cfg.freq_window_periods * period))))
    rows = []
    for a in range(lo, n - w + 1, w):
        seg = q_s[a : a + w]
        if metrics.g_rms_spread(seg, G) < cfg.min_amplitude * q_std:
            continue
        a_ = np.array([min(a, n - 3)])
        q0, v0 = initial_state(q_s, a_, dt)
        sim, _ = rollout(model, q0, v0, dt, w, u=actuation_schedule(u[a : a + w][None], dt))
        sim = sim[0].numpy()
        f_seg = timeseries.spectral_peak_frequency(metrics.project(seg, top), dt)
        rows.append((f_seg, timeseries.spectral_peak_frequency(metrics.project(sim, top), dt) if np.isfinite(sim).all() else float("nan")))
    return np.array([r[0] for r in rows]), np.array([r[1] for r in rows]), w


def held_out_damping(model: Lagrangian, q_s: np.ndarray, u: np.ndarray, dt: float, top: np.ndarray, cfg: EvalConfig, f_enc: float) -> dict[str, dict]:
    """``zeta_enc`` and ``zeta_sim``: the damping ratio of the encoded held-out segment and of one free rollout of the
    model through it from its first usable frame (:func:`lagsplat.metrics.rollout_start`), by the same estimator
    (:func:`lagsplat.evaluate.in_sample.damping_ratio`: exponential envelope of the half-cycle amplitudes of the
    projection on ``G_bar``'s top direction ``top``); ``None`` with fewer than three half cycles.

    Args:
        model: the Lagrangian; ``q_s [n, d]`` the smoothed held-out segment, ``u [n, n_u]`` its actuation;
        dt: frame interval, s; cfg: settings (``sigma``); f_enc: the segment's frequency, Hz.
    """
    from lagsplat.evaluate.in_sample import ENVELOPE as env, damping_ratio, free_rollout_projection

    n = len(q_s)
    lo = metrics.rollout_start(cfg.sigma, n, 16)
    z_enc = damping_ratio(metrics.project(q_s[lo:], top), dt, f_enc)
    p_sim = free_rollout_projection(model, q_s, u, dt, top, lo)
    z_sim = None if p_sim is None else damping_ratio(p_sim, dt, float(timeseries.spectral_peak_frequency(p_sim, dt)))
    span = f"the held-out segment from frame {lo} ({(n - lo) * dt:.2f} s)"
    return {
        "zeta_enc": metric_entry(z_enc, f"damping ratio of the encoded held-out video; {env}", span, "1"),
        "zeta_sim": metric_entry(z_sim, f"damping ratio of the model's free rollout through the held-out segment; {env}", span, "1"),
    }


def modal_metrics(clip: Clip, chart: Chart, model: Lagrangian) -> dict[str, dict]:
    """The model's linearised modes at rest, and their errors against the clip's known truth when it has one."""
    out: dict[str, dict] = {}
    modes = model.modal_analysis()
    out["f_modes_hz"] = metric_entry(
        modes["f_hz"].tolist(),
        "natural frequencies of the model linearised at its rest state: |lambda| / 2 pi of the quadratic "
        "eigenproblem (lambda^2 M + lambda C + K) phi = 0, K = Hessian of V; chart-independent",
        "rest state",
        "Hz",
    )
    out["zeta_modes"] = metric_entry(modes["zeta"].tolist(), "damping ratio -Re(lambda) / |lambda| of each mode (same eigenproblem)", "rest state", "1")
    truth = clip.meta.get("truth", {})
    if "f_modes_hz" in truth and len(truth["f_modes_hz"]) == chart.d:
        f_t, z_t = np.sort(np.asarray(truth["f_modes_hz"], float)), np.asarray(truth["zeta_modes"], float)[np.argsort(truth["f_modes_hz"])]
        out["eps_modes_freq"] = metric_entry(
            (np.abs(modes["f_hz"] - f_t) / f_t).tolist(), "|f_mode - f_mode_truth| / f_mode_truth per mode (sorted by frequency)", "rest state", "fraction"
        )
        out["eps_modes_zeta"] = metric_entry(
            (np.abs(modes["zeta"] - z_t) / z_t).tolist(), "|zeta_mode - zeta_mode_truth| / zeta_mode_truth per mode", "rest state", "fraction"
        )
    return out
