"""Stage 1 until the chart passes the quality gate: retries within a budget, every attempt recorded.

A Stage-1 run can fail for reasons a second run fixes: an unlucky
initialisation that leaves the moving object out of the decoder, or too few
steps for a cluttered scene. :func:`train_stage1_gated` trains, builds the
chart (paper §3.2) and runs the gate (:func:`lagsplat.chart.gate.chart_gate`);
when the chart fails, it trains again with another seed, more steps and more
Gaussians (from the second retry on, where the object was left out, the first
budget with the anchored start of :mod:`lagsplat.train.anchor`), up to
``retries`` times, and keeps the first attempt that passes
(or, when none does, the one with the fewest failed checks). A retry after a
torn chart (the continuity check failed) also turns on the temporal prior
(``Stage1Config.w_temporal``, :data:`TEAR_W_TEMPORAL`): on a large rotation or
a small fast bob the encoder can map neighbouring frames far apart, and the
second difference of consecutive encodings is what penalises exactly that. It
stays off on a first attempt, because on a chart that does not tear it can
shrink the decoder's motion (fewer moving pixels covered).
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

from lagsplat.chart.gate import chart_key, chart_record, gate_summary, gated_chart
from lagsplat.io.clip import Clip
from lagsplat.models.autoencoder import AutoEncoder
from lagsplat.train.stage1 import Stage1Config, train_stage1
from lagsplat.views import ViewSet

__all__ = ["retry_config", "train_stage1_gated"]

#: Growth of the Stage-1 budget per retry: steps and Gaussians.
STEP_GROWTH, GAUSSIAN_GROWTH = 1.5, 1.5
#: Weight of the temporal prior on a retry after a torn chart (when the configured weight is lower).
TEAR_W_TEMPORAL = 1.0
#: Encoder steps on the object's path of an anchored retry (:func:`retry_config`).
ANCHOR_STEPS = 300


def retry_config(cfg: Stage1Config, attempt: int, torn: bool = False, undrawn: bool = False) -> Stage1Config:
    """The settings of retry ``attempt`` (0: ``cfg`` itself).

    Steps and Gaussians grow by 1.5x per retry; ``torn`` (an earlier attempt's chart failed the
    continuity check) raises ``w_temporal`` to at least :data:`TEAR_W_TEMPORAL`. From the second retry on,
    where the earlier attempts left the object out (``undrawn``: the decoder-motion or the coverage check
    failed) and ``cfg`` does not anchor its start, the retry is the first attempt's budget with the anchored
    start (:mod:`lagsplat.train.anchor`, :data:`ANCHOR_STEPS` steps): a small object that more steps and
    Gaussians did not draw.
    """
    if attempt == 0:
        return cfg
    if attempt >= 2 and undrawn and cfg.anchor_steps == 0 and cfg.decoder == "conditioned":
        return dataclasses.replace(cfg, anchor_steps=ANCHOR_STEPS)
    w_temporal = max(cfg.w_temporal, TEAR_W_TEMPORAL) if torn else cfg.w_temporal
    return dataclasses.replace(
        cfg, steps=int(round(cfg.steps * STEP_GROWTH**attempt)), n_gaussians=int(round(cfg.n_gaussians * GAUSSIAN_GROWTH**attempt)),
        w_temporal=w_temporal,
    )  # fmt: skip


def train_stage1_gated(
    clip: Clip,
    cfg: Stage1Config,
    d: int,
    seed: int = 0,
    retries: int = 1,
    chart_kwargs: dict[str, Any] | None = None,
    progress: bool = True,
    device: str = "cpu",
    label: str = "stage1",
    views: ViewSet | None = None,
) -> tuple[AutoEncoder, dict, list[dict[str, Any]]]:
    """Train Stage 1, retrying while the chart fails the gate.

    Args:
        clip, cfg, d, progress, device, label, views: as :func:`lagsplat.train.stage1.train_stage1`.
        seed: seed of the first attempt; retry ``k`` uses ``seed + 1000 k``.
        retries: attempts after the first (0: train once; the gate is still run and recorded).
        chart_kwargs: :func:`lagsplat.chart.build_chart` keywords (``n_metric_samples``, ``rho``,
            ``refine_iters``) of the chart the gate reads.

    Returns:
        ``(model, history, attempts)``: the kept model and its training history, with ``history["gated_chart"]``
        its gated chart (:func:`lagsplat.chart.gate.chart_record`, what the chart stage would build); ``attempts``
        one entry per attempt: ``seed``, ``steps`` (at most), ``steps_run``, ``stopped`` (why it
        stopped early, or ``None``), ``n_gaussians``, ``w_temporal``, ``wall_s``, ``gate``
        (:func:`lagsplat.chart.gate.chart_gate`'s result) and ``kept``.

    Raises:
        ValueError: as :func:`lagsplat.train.stage1.train_stage1`, or for ``retries < 0``.
    """
    if retries < 0:
        raise ValueError(f"stage1.retries must be >= 0, got {retries}")
    kw = dict(chart_kwargs or {})
    attempts: list[dict[str, Any]] = []
    best, torn, undrawn = None, False, False
    for k in range(retries + 1):
        c = retry_config(cfg, k, torn=torn, undrawn=undrawn)
        s = seed + 1000 * k
        t0 = time.perf_counter()
        model, hist = train_stage1(clip, c, d, seed=s, progress=progress, device=device, label=f"{label} attempt {k + 1}" if k else label, views=views)
        chart, gate = gated_chart(model, clip, seed=seed, **kw)  # the chart stage's own chart
        stopped = hist.get("stopped") or {}
        attempts.append({"seed": s, "steps": c.steps, "steps_run": stopped.get("step", c.steps), "stopped": stopped.get("reason"),
                         "n_gaussians": c.n_gaussians, "w_temporal": c.w_temporal, "anchor_steps": c.anchor_steps,
                         "wall_s": round(time.perf_counter() - t0, 1), "gate": gate, "kept": False})  # fmt: skip
        ran = f"{stopped['step']} of {c.steps} steps ({stopped['reason']})" if stopped else f"{c.steps} steps"
        prior = (f", temporal prior {c.w_temporal:g}" if c.w_temporal > 0 else "") + (", anchored start" if c.anchor_steps > 0 else "")
        print(f"[lagsplat] {label}: attempt {k + 1} (seed {s}, {ran}, {c.n_gaussians} Gaussians{prior}): chart {gate_summary(gate)}", flush=True)
        torn = torn or not gate["checks"]["continuity"]["ok"]
        undrawn = undrawn or not (gate["checks"]["decoder_motion"]["ok"] and gate["checks"]["coverage"]["ok"])
        score = len(gate["reasons"])
        if best is None or score < best[0]:
            hist["gated_chart"] = chart_record(chart, gate, chart_key(clip, seed=seed, **kw))
            best = (score, k, model, hist)
        if gate["passed"]:
            break
    _, k, model, hist = best
    attempts[k]["kept"] = True
    return model, hist, attempts
