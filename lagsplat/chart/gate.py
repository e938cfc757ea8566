"""The chart-quality gate: whether a Stage-1 chart is good enough to identify dynamics on.

Everything after Stage 1 reads the chart (paper §3.2 "Reading the chart"):
Stage 2 fits the Lagrangian to the encoded trajectory, the evaluation rolls it
out in the chart, the forces pull back through the decoder Jacobian. A chart
that tears, or a decoder that never learned to draw the moving object, gives
numbers that look fine and mean nothing. :func:`chart_gate` reads four
statistics off the trained autoencoder, the clip and the chart, each with a
threshold fixed in :class:`GateThresholds`:

* ``continuity``: :func:`speed_jump_ratio`, the largest jump of the chart
  speed between neighbouring frame steps. A tear (the encoder switching branch)
  is a step far longer than the steps around it; an impact (a bounce off an end
  stop) reverses the velocity but keeps its size, so it passes.
* ``decoder_motion``: ``lambda_max(G_bar)`` (the image MSE of one standard
  deviation of ``q`` along the most visible direction; the chart is whitened)
  over the autoencoder floor on the training frames.
* ``coverage``: :func:`moving_pixel_r2`, the share of the moving pixels'
  temporal variance that the decoded chart reproduces. A decoder that draws
  the static scene and leaves the moving object out scores about 0.
* ``saturation``: :func:`encoder_saturation`, how far the decoder-refined
  latents (:func:`lagsplat.chart.refine.refine_latents`) of the most extreme frames
  lie beyond their encodings: an encoder that saturates at the turning points
  reads a compressed amplitude.

:func:`gated_chart` builds the chart a run uses: with ``chart.refine_iters > 0``
the refined chart where it passes the gate and is the less noisy one
(:func:`relative_chart_noise`), else the encoder's. Stage 1 builds that chart to
gate its attempts; :func:`chart_record` keeps it with the checkpoint under a
:func:`chart_key` of everything it depends on besides the autoencoder, so the
chart stage reads it back (:func:`chart_from_record`) instead of building it
again when nothing changed.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np
import torch

from lagsplat.chart import Chart, build_chart
from lagsplat.chart.refine import refine_latents
from lagsplat.io.clip import HELD_OUT, TRAIN, Clip, segments
from lagsplat.models.autoencoder import AutoEncoder, frames_to_tensor
from lagsplat.motion import motion_masks
from lagsplat.timeseries import chart_noise

__all__ = ["GateThresholds", "speed_jump_ratio", "moving_pixel_r2", "encoder_saturation", "chart_gate", "gate_summary",
           "relative_chart_noise", "gated_chart", "chart_key", "chart_record", "chart_from_record"]


@dataclass(frozen=True)
class GateThresholds:
    """The gate's thresholds, fixed before any suite was scored with them.

    Attributes:
        max_speed_jump: largest :func:`speed_jump_ratio` of a continuous chart.
        min_decoder_motion: smallest ``lambda_max(G_bar) / AE floor``.
        min_coverage: smallest :func:`moving_pixel_r2`.
        max_saturation: largest :func:`encoder_saturation`.
    """

    max_speed_jump: float = 4.0
    min_decoder_motion: float = 1.0
    min_coverage: float = 0.5
    max_saturation: float = 0.25


def speed_jump_ratio(q: np.ndarray, G_bar: np.ndarray, split: np.ndarray, episode: np.ndarray | None = None) -> tuple[float, int]:
    """The largest jump of the chart speed between neighbouring steps, and the frame where it happens.

    With ``s_t = |q_{t+1} - q_t|_G`` (the step length in the metric ``G_bar``,
    within each contiguous split segment) and ``m`` the median step, the
    statistic is the largest of

    * ``s_t / max(s_{t-1}, s_{t+1}, m)``: one step far longer than both
      neighbours (the chart jumps to another branch and stays), and
    * ``min(s_{t-1}, s_t) / max(s_{t-2}, s_{t+1}, m)``: two long steps out and
      back between short ones (a one-frame excursion).

    A smooth motion sampled at ``N`` frames per period gives about
    ``1 + 2 pi / N``; an impact with restitution ``e`` about ``1 / e``
    (speed is kept, only its direction turns); a tear gives the ratio of the
    jump to the motion per frame, usually far above 4. The floor ``m`` keeps
    noise at rest from counting.

    Args:
        q: ``[T,d]`` chart coordinates.
        G_bar: ``[d,d]`` visibility metric.
        split: ``[T]`` split labels; segments of 4 frames or more are read.
        episode: ``[T]`` recording index, or ``None``.

    Returns:
        ``(ratio, frame)``; ``(nan, -1)`` when no segment is long enough.
    """
    G = 0.5 * (G_bar + G_bar.T)
    best, where = float("nan"), -1
    steps = []
    segs = [s for s in segments(split, TRAIN, episode) + segments(split, HELD_OUT, episode) if len(s) >= 4]
    for seg in segs:
        dq = np.diff(q[seg], axis=0)
        steps.append(np.sqrt(np.maximum(np.einsum("ti,ij,tj->t", dq, G, dq), 0.0)))
    if not steps:
        return best, where
    m = max(float(np.median(np.concatenate(steps))), 1e-12)
    for seg, s in zip(segs, steps):
        pad = np.concatenate([[0.0, 0.0], s, [0.0, 0.0]])  # s_{t-2} .. s_{t+2} with zeros beyond the segment
        prev2, prev, cur, nxt = pad[:-4], pad[1:-3], pad[2:-2], pad[3:-1]
        single = cur / np.maximum(np.maximum(prev, nxt), m)
        double = np.minimum(prev, cur) / np.maximum(np.maximum(prev2, nxt), m)
        r = np.maximum(single, double)
        k = int(np.argmax(r))
        if not np.isfinite(best) or r[k] > best:
            best, where = float(r[k]), int(seg[k])
    return best, where


def _pick(n: int, limit: int) -> np.ndarray:
    """At most ``limit`` evenly spaced indices into ``range(n)``."""
    return np.unique(np.linspace(0, n - 1, min(n, limit)).round().astype(int))


@torch.no_grad()
def moving_pixel_r2(model: AutoEncoder, clip: Clip, chart: Chart, max_frames: int = 256) -> tuple[float, float]:
    """The share of the moving pixels' temporal variance that the decoded chart reproduces.

    On (at most ``max_frames`` evenly spaced) training frames, the moving pixels
    are those whose temporal standard deviation reaches a quarter of the largest
    (:func:`lagsplat.motion.motion_masks`); the score is
    ``1 - sum (x - decode(z))^2 / sum (x - mean_t x)^2`` over them, all channels.
    A decoder that draws only the static scene scores about 0, one that draws the
    motion up to noise close to 1.

    Returns:
        ``(r2, moving_fraction)``: the score and the moving pixels' share of the frame;
        ``(nan, 0)`` when nothing moves.
    """
    idx = clip.train_idx[_pick(len(clip.train_idx), max_frames)]
    frames = clip.images[idx]
    try:
        moving, _, _ = motion_masks(frames, sigma=1.0)
    except ValueError:
        return float("nan"), 0.0
    z = chart.q[idx] @ chart.W_inv + chart.mean
    x = frames_to_tensor(frames).numpy()
    rec = np.concatenate([model.decode(torch.as_tensor(z[i : i + 64], dtype=torch.float32)).numpy() for i in range(0, len(z), 64)])
    xm, rm = x[:, :, moving], rec[:, :, moving]
    var = float(((xm - xm.mean(0, keepdims=True)) ** 2).sum())
    if var <= 0:
        return float("nan"), float(moving.mean())
    return 1.0 - float(((xm - rm) ** 2).sum()) / var, float(moving.mean())


def encoder_saturation(model: AutoEncoder, clip: Clip, chart: Chart, share: float = 0.03, iters: int = 8) -> float:
    """How far beyond the encoded extremes the decoder places the most extreme frames.

    Along ``G_bar``'s most visible direction ``v``, the ``share`` of training
    frames with the largest and the smallest ``p = q v`` are refined by
    :func:`lagsplat.chart.refine.refine_latents` (per frame, to where the decoder draws
    them best). The statistic is ``(range_refined - range_encoded) / range_encoded``
    with ``range`` the difference of the two groups' mean ``p``: 0 for an
    encoder that reads the turning points where the decoder draws them, 0.3 for
    one that reads 30 % of the amplitude short.

    Returns:
        The statistic (dimensionless; ``nan`` with fewer than 8 training frames).
    """
    tr = clip.train_idx
    if len(tr) < 8:
        return float("nan")
    lam, V = np.linalg.eigh(0.5 * (chart.G_bar + chart.G_bar.T))
    v = V[:, np.argmax(lam)]
    p = chart.q[tr] @ v
    k = max(2, int(round(share * len(tr))))
    order = np.argsort(p)
    lo, hi = tr[order[:k]], tr[order[-k:]]
    pick = np.concatenate([lo, hi])
    z = chart.q[pick] @ chart.W_inv + chart.mean
    z_ref, _ = refine_latents(model, clip.images[pick], z, iters)
    p_ref = ((z_ref - chart.mean) @ chart.W) @ v
    enc = float(p[order[-k:]].mean() - p[order[:k]].mean())
    ref = float(p_ref[k:].mean() - p_ref[:k].mean())
    return (ref - enc) / max(abs(enc), 1e-12)


def chart_gate(model: AutoEncoder, clip: Clip, chart: Chart, thresholds: GateThresholds | None = None) -> dict[str, Any]:
    """Run the four checks of the gate (module docstring) and say whether the chart passes.

    Args:
        model: the trained autoencoder of the chart.
        clip: the clip it was trained on.
        chart: its chart (:func:`lagsplat.chart.build_chart`).
        thresholds: :class:`GateThresholds` (default: the fixed ones).

    Returns:
        ``{"passed": bool, "reasons": [one line per failed check], "checks": {name:
        {"value", "threshold", "ok", "text"}}, "thresholds": {...}}``; a check whose
        statistic cannot be computed (``nan``) is reported and does not fail.
    """
    th = thresholds or GateThresholds()
    jump, at = speed_jump_ratio(chart.q, chart.G_bar, chart.split, chart.episode)
    lam = float(np.linalg.eigvalsh(0.5 * (chart.G_bar + chart.G_bar.T)).max())
    motion = lam / chart.ae_floor_train if chart.ae_floor_train > 0 else float("inf")
    r2, moving_frac = moving_pixel_r2(model, clip, chart)
    sat = encoder_saturation(model, clip, chart)
    rows = {
        "continuity": (jump, th.max_speed_jump, "<", f"chart speed jumps {jump:.3g}x between neighbouring steps at frame {at}"),
        "decoder_motion": (motion, th.min_decoder_motion, ">", f"the decoder's image change per std of q is {motion:.3g}x the AE floor"),
        "coverage": (r2, th.min_coverage, ">", f"the decoded chart reproduces {r2:.3g} of the moving pixels' variance ({100 * moving_frac:.1f}% of the frame moves)"),
        "saturation": (sat, th.max_saturation, "<", f"the decoder places the extreme frames {sat:.3g} of the encoded range beyond the encodings"),
    }
    checks, reasons = {}, []
    for name, (value, limit, sense, text) in rows.items():
        ok = (not np.isfinite(value)) or (value < limit if sense == "<" else value > limit)
        checks[name] = {"value": float(value), "threshold": float(limit), "ok": bool(ok), "text": text}
        if not ok:
            reasons.append(f"{name}: {text} (need {sense} {limit:g})")
    return {"passed": not reasons, "reasons": reasons, "checks": checks, "thresholds": asdict(th), "jump_frame": at}


def gate_summary(gate: dict[str, Any]) -> str:
    """One line: ``passed`` or ``failed: <reasons joined by '; '>``."""
    return "passed" if gate.get("passed") else "failed: " + "; ".join(gate.get("reasons", []))


def relative_chart_noise(chart: Chart) -> float:
    """The chart's white-noise level on its training frames over their spread (rms over coordinates, dimensionless).

    :func:`lagsplat.timeseries.chart_noise` (fourth differences, robust scale) per coordinate of the training
    segments, divided by that coordinate's standard deviation there; ``nan`` without a segment of 5 frames.
    """
    segs = [chart.q[s] for s in chart.segments(TRAIN) if len(s) >= 5]
    if not segs:
        return float("nan")
    q = np.concatenate(segs, 0)
    rel = chart_noise(segs) / np.maximum(q.std(0), 1e-12)
    return float(np.sqrt(np.mean(rel**2)))


def gated_chart(
    model: AutoEncoder, clip: Clip, n_metric_samples: int = 64, rho: float = 0.01, seed: int = 0, refine_iters: int = 0,
    thresholds: GateThresholds | None = None,
) -> tuple[Chart, dict[str, Any]]:
    """The chart a run uses, and its gate: the refined chart where it is the cleaner one and holds, else the encoder's.

    With ``refine_iters > 0`` both charts are built (:func:`lagsplat.chart.build_chart`): the encoder's (paper §3.2)
    and the one whose encodings took ``refine_iters`` Levenberg-Marquardt steps towards where the decoder draws each
    frame (:func:`lagsplat.chart.refine.refine_latents`). Per frame the refinement gives up the encoder's temporal
    regularity: it can lower the chart's noise or tear the chart (both measured on rendered and real clips,
    ``docs/experiments/diagnosis_history.md``). So the refined chart is used only when it passes the gate and its
    :func:`relative_chart_noise` is below the encoder's; otherwise the encoder's chart is used, unless it alone fails
    the gate. ``chart.meta["refine_choice"]`` records both noise levels and the reason.

    Args:
        model: the trained autoencoder.
        clip: the clip it was trained on.
        n_metric_samples, rho, seed: :func:`lagsplat.chart.build_chart` settings.
        refine_iters: refinement steps per frame (0: the encoder's chart only).
        thresholds: :class:`GateThresholds` (default: the fixed ones).

    Returns:
        ``(chart, gate)`` with ``gate`` the :func:`chart_gate` result of the chart returned.
    """
    plain = build_chart(model, clip, n_metric_samples, rho, seed, 0)
    if int(refine_iters) <= 0:
        return plain, chart_gate(model, clip, plain, thresholds)
    refined = build_chart(model, clip, n_metric_samples, rho, seed, int(refine_iters))
    noise = {"encoder": relative_chart_noise(plain), "refined": relative_chart_noise(refined)}
    g_ref = chart_gate(model, clip, refined, thresholds)
    cleaner = bool(noise["refined"] < noise["encoder"])
    if g_ref["passed"] and cleaner:
        chart, gate, why = refined, g_ref, "refined: it passes the gate with less noise than the encoder's"
    else:
        g_plain = chart_gate(model, clip, plain, thresholds)
        if g_ref["passed"] and not g_plain["passed"]:
            chart, gate, why = refined, g_ref, "refined: the encoder's chart fails the gate"
        else:
            chart, gate = plain, g_plain
            why = "encoder's: " + ("the refined chart is not less noisy" if g_ref["passed"] else "the refined chart fails the gate (" + gate_summary(g_ref) + ")")
    chart.meta["refine_choice"] = {"refine_iters": int(refine_iters), "used": "refined" if chart is refined else "encoder",
                                   "relative_noise": noise, "reason": why}  # fmt: skip
    return chart, gate


def chart_key(clip: Clip, n_metric_samples: int = 64, rho: float = 0.01, seed: int = 0, refine_iters: int = 0) -> str:
    """A fingerprint (SHA-256, hex) of what :func:`gated_chart` reads besides the autoencoder.

    The clip's frames, timestamps, split, recording indices and actuation, and the chart settings: two
    calls with equal keys on the same autoencoder build the same chart.
    """
    h = hashlib.sha256()
    for a in (clip.images, clip.t, clip.split, clip.episode, clip.u):
        arr = np.ascontiguousarray(a)
        h.update(f"{arr.dtype}{arr.shape}".encode())
        h.update(arr.tobytes())
    h.update(json.dumps([int(n_metric_samples), float(rho), int(seed), int(refine_iters)]).encode())
    return h.hexdigest()


def chart_record(chart: Chart, gate: dict[str, Any], key: str) -> dict[str, Any]:
    """A gated chart as plain values (arrays, numbers, dicts) to keep with the Stage-1 checkpoint, under ``key``
    (:func:`chart_key`)."""
    return {"key": key, "chart": {f.name: getattr(chart, f.name) for f in fields(Chart)}, "gate": gate}


def chart_from_record(record: dict[str, Any] | None, key: str) -> tuple[Chart, dict[str, Any]] | None:
    """``(chart, gate)`` of a :func:`chart_record` made under ``key``; ``None`` when there is none or its key differs
    (another clip or other chart settings: the chart must be built again)."""
    if not isinstance(record, dict) or record.get("key") != key:
        return None
    values = record["chart"]
    chart = Chart(**{f.name: values[f.name] for f in fields(Chart)})
    chart.meta = json.loads(json.dumps(chart.meta))  # a copy: the caller adds to it
    return chart, record["gate"]
