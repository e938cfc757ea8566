"""The chart-quality gate (lagsplat.chart.gate): tears against impacts, decoder motion, coverage, saturation."""

from __future__ import annotations

import numpy as np
import torch

from lagsplat.chart import build_chart
from lagsplat.chart.gate import chart_gate, encoder_saturation, gate_summary, moving_pixel_r2, speed_jump_ratio
from lagsplat.io.clip import Clip
from lagsplat.models.autoencoder import AutoEncoder

T = 300
SPLIT = np.zeros(T, np.int8)


def _sine(f: float = 0.7) -> np.ndarray:
    return np.sin(2 * np.pi * f * np.arange(T) / 30.0)[:, None]


def test_a_smooth_oscillation_is_continuous():
    r, _ = speed_jump_ratio(_sine(), np.eye(1), SPLIT)
    assert r < 2.0


def test_a_one_frame_excursion_and_a_branch_switch_are_tears():
    spike = _sine()
    spike[120] += 1.5  # the encoder reads one frame on another branch
    r, at = speed_jump_ratio(spike, np.eye(1), SPLIT)
    assert r > 4.0 and at in (119, 120)
    step = _sine()
    step[150:] += 1.0  # the chart switches branch and stays
    r, at = speed_jump_ratio(step, np.eye(1), SPLIT)
    assert r > 4.0 and at == 149


def test_an_impact_is_not_a_tear():
    """A cart bouncing off an end stop: the velocity reverses, its size is kept up to the restitution."""
    x, v, e, dt, out = 0.0, 1.2, 0.6, 1 / 30, []
    for _ in range(T):
        v -= 4.0 * x * dt  # a soft spring pulls back towards 0
        x += v * dt
        if x > 0.25:  # hard stop at 0.25: reflected with restitution e
            x, v = 0.25 - e * (x - 0.25), -e * v
        out.append(x)
    q = np.array(out)[:, None]
    r, _ = speed_jump_ratio(q, np.eye(1), SPLIT)
    assert r < 1 / e + 1.0


def _blob_autoencoder(moves: bool = True, size: int = 24, saturate: float = 0.8) -> AutoEncoder:
    from lagsplat.viewer.synthetic import decoder_from_primitives

    class Centroid(torch.nn.Module):  # the blob's horizontal centroid, 4 px per unit, saturating at +-saturate
        def forward(self, x: torch.Tensor) -> torch.Tensor:
            w = x.mean(1).sum(1)
            cols = torch.arange(x.shape[-1], dtype=x.dtype)
            c = (w * cols).sum(1) / w.sum(1).clamp_min(1e-6) - (x.shape[-1] - 1) / 2
            return (c / 4.0).clamp(-saturate, saturate)[:, None]

    J = [[4.0, 0.0]] if moves else [[0.0, 0.0]]
    dec = decoder_from_primitives([[size / 2 - 0.5, size / 2 - 0.5]], [J[0]], [[0.9, 0.9, 0.9]], [0.95], [2.5], size, size)
    return AutoEncoder(Centroid(), dec, size, size)


def _clip(amplitude: float, n: int = 120) -> Clip:
    ae = _blob_autoencoder()
    z = amplitude * np.sin(2 * np.pi * np.arange(n) / 30.0)[:, None]
    with torch.no_grad():
        img = ae.decode(torch.as_tensor(z, dtype=torch.float32)).clamp(0, 1)
    frames = (img.permute(0, 2, 3, 1).numpy() * 255).round().astype(np.uint8)
    split = np.zeros(n, np.int8)
    split[int(0.7 * n) :] = 1
    return Clip(images=frames, t=np.arange(n) / 30.0, split=split)


def test_a_decoder_that_draws_the_motion_passes():
    clip, ae = _clip(0.6), _blob_autoencoder()
    chart = build_chart(ae, clip, n_metric_samples=8)
    r2, moving = moving_pixel_r2(ae, clip, chart)
    assert r2 > 0.8 and 0 < moving < 0.5
    assert abs(encoder_saturation(ae, clip, chart)) < 0.05
    gate = chart_gate(ae, clip, chart)
    assert gate["passed"], gate["reasons"]
    assert gate_summary(gate) == "passed"


def test_a_decoder_that_leaves_the_object_out_fails_coverage():
    """The decoder draws the blob where it rests and never moves it (as a decoder that learned only the static scene)."""
    clip, ae = _clip(0.6), _blob_autoencoder(moves=False)
    chart = build_chart(ae, clip, n_metric_samples=8)
    gate = chart_gate(ae, clip, chart)
    assert not gate["passed"]
    assert gate["checks"]["coverage"]["value"] < 0.2 and not gate["checks"]["coverage"]["ok"]
    assert not gate["checks"]["decoder_motion"]["ok"]
    assert gate_summary(gate).startswith("failed: ") and "coverage" in gate_summary(gate)


def test_an_encoder_that_saturates_at_the_turning_points_fails():
    clip, ae = _clip(1.2), _blob_autoencoder(saturate=0.8)  # reads the extremes at 0.8 of 1.2
    chart = build_chart(ae, clip, n_metric_samples=8)
    sat = encoder_saturation(ae, clip, chart)
    assert sat > 0.25
    gate = chart_gate(ae, clip, chart)
    assert not gate["checks"]["saturation"]["ok"] and any(r.startswith("saturation") for r in gate["reasons"])


def test_stage1_retries_while_the_gate_fails_and_records_every_attempt():
    import dataclasses

    from lagsplat.synth.pendulum import make_pendulum_clip
    from lagsplat.train.attempts import retry_config, train_stage1_gated
    from lagsplat.train.stage1 import Stage1Config

    clip = make_pendulum_clip(size=(24, 24), duration_s=6.0)
    cfg = dataclasses.replace(Stage1Config(), n_gaussians=32, steps=2, recycle_warmup=1, recycle_every=1)  # two steps draw no motion
    assert retry_config(cfg, 1).steps == 3 and retry_config(cfg, 1).n_gaussians == 48 and retry_config(cfg, 0) is cfg
    assert retry_config(cfg, 1).w_temporal == 0.0 and retry_config(cfg, 1, torn=True).w_temporal == 1.0  # a tear turns the prior on
    assert retry_config(dataclasses.replace(cfg, w_temporal=2.0), 1, torn=True).w_temporal == 2.0  # and never lowers it
    # the second retry, where the object was left out: the first budget with the anchored start
    assert retry_config(cfg, 2, undrawn=True) == dataclasses.replace(cfg, anchor_steps=300)
    assert retry_config(cfg, 1, undrawn=True).anchor_steps == 0 and retry_config(cfg, 2).steps == round(2 * 2.25)
    model, hist, attempts = train_stage1_gated(clip, cfg, 1, seed=3, retries=1, chart_kwargs={"n_metric_samples": 8}, progress=False)
    assert [a["seed"] for a in attempts] == [3, 1003] and [a["steps"] for a in attempts] == [2, 3]
    assert all(not a["gate"]["passed"] for a in attempts) and sum(a["kept"] for a in attempts) == 1
    torn = not attempts[0]["gate"]["checks"]["continuity"]["ok"]
    assert [a["w_temporal"] for a in attempts] == [0.0, 1.0 if torn else 0.0]
    kept = next(a for a in attempts if a["kept"])
    assert len(kept["gate"]["reasons"]) == min(len(a["gate"]["reasons"]) for a in attempts)
    assert model.decoder.K == kept["n_gaussians"]


def test_gated_chart_takes_the_refined_chart_where_the_encoders_fails_the_gate():
    from lagsplat.chart.gate import gated_chart

    clip, ae = _clip(1.2), _blob_autoencoder(saturate=0.8)  # the encoder reads the extremes at 0.8 of 1.2
    plain, gate = gated_chart(ae, clip, n_metric_samples=8, refine_iters=0)
    assert not gate["passed"] and "refine_choice" not in plain.meta and plain.meta["refine_iters"] == 0
    chart, gate = gated_chart(ae, clip, n_metric_samples=8, refine_iters=8)
    assert gate["passed"], gate["reasons"]
    choice = chart.meta["refine_choice"]
    assert chart.meta["refine_iters"] == 8 and choice["used"] == "refined"
    assert set(choice["relative_noise"]) == {"encoder", "refined"}
    assert np.ptp(chart.q[:, 0]) > 0  # the refined amplitude, not the clamped one
    assert abs(encoder_saturation(ae, clip, chart)) < 0.05


def test_gated_chart_keeps_the_encoders_chart_where_refinement_adds_noise(monkeypatch):
    import lagsplat.chart.gate as cg

    clip, ae = _clip(0.6), _blob_autoencoder()  # both charts pass the gate
    monkeypatch.setattr(cg, "relative_chart_noise", lambda chart: 0.02 if chart.meta["refine_iters"] else 0.01)
    chart, gate = cg.gated_chart(ae, clip, n_metric_samples=8, refine_iters=8)
    assert gate["passed"] and chart.meta["refine_iters"] == 0
    assert chart.meta["refine_choice"]["used"] == "encoder" and "not less noisy" in chart.meta["refine_choice"]["reason"]
    monkeypatch.setattr(cg, "relative_chart_noise", lambda chart: 0.005 if chart.meta["refine_iters"] else 0.01)
    chart, gate = cg.gated_chart(ae, clip, n_metric_samples=8, refine_iters=8)
    assert chart.meta["refine_iters"] == 8 and chart.meta["refine_choice"]["used"] == "refined"


def test_relative_chart_noise_reads_the_white_noise_over_the_spread():
    import dataclasses

    from lagsplat.chart.gate import relative_chart_noise

    clip, ae = _clip(0.6, n=600), _blob_autoencoder()
    chart = build_chart(ae, clip, n_metric_samples=8)
    rng = np.random.default_rng(0)
    s = np.sin(2 * np.pi * 0.5 * np.arange(600) / 30.0)[:, None]
    for level in (0.005, 0.02):
        noisy = dataclasses.replace(chart, q=s + level * s[chart.split == 0].std() * rng.standard_normal(s.shape))
        assert abs(relative_chart_noise(noisy) / level - 1.0) < 0.2


def test_the_chart_stage_reads_the_chart_stage1_gated_and_builds_it_again_when_a_setting_changed(tmp_path):
    """Stage 1 keeps the gated chart of its kept attempt; for the same clip and settings it is the chart the chart
    stage would build from the saved checkpoint, for another setting or another clip there is none to read."""
    import dataclasses

    from lagsplat.chart.gate import chart_from_record, chart_key, gated_chart
    from lagsplat.models.autoencoder import load_stage1, save_stage1
    from lagsplat.synth.pendulum import make_pendulum_clip
    from lagsplat.train.attempts import train_stage1_gated
    from lagsplat.train.stage1 import Stage1Config

    clip = make_pendulum_clip(size=(24, 24), duration_s=6.0)
    cfg = dataclasses.replace(Stage1Config(), n_gaussians=32, steps=30, recycle_warmup=10, recycle_every=10)
    kw = {"n_metric_samples": 8, "rho": 0.01, "refine_iters": 0}
    model, hist, _ = train_stage1_gated(clip, cfg, 1, seed=2, retries=0, chart_kwargs=kw, progress=False)
    path = save_stage1(tmp_path / "stage1.pt", model, dataclasses.asdict(cfg), hist, 1)
    record = torch.load(path, map_location="cpu", weights_only=False)["history"]["gated_chart"]
    kept = chart_from_record(record, chart_key(clip, seed=2, **kw))
    assert kept is not None
    built, gate = gated_chart(load_stage1(path), clip, seed=2, **kw)
    chart, kept_gate = kept
    for name in ("q", "G_bar", "A", "W", "mean", "ae_mse"):
        np.testing.assert_allclose(getattr(chart, name), getattr(built, name), rtol=1e-6, atol=1e-9, err_msg=name)
    assert kept_gate["passed"] == gate["passed"] and kept_gate["reasons"] == gate["reasons"]
    assert chart_from_record(record, chart_key(clip, seed=2, **{**kw, "n_metric_samples": 16})) is None  # another setting
    other = dataclasses.replace(clip, images=clip.images[:, ::-1].copy())
    assert chart_from_record(record, chart_key(other, seed=2, **kw)) is None  # another clip
    assert chart_from_record(None, chart_key(clip, seed=2, **kw)) is None  # a checkpoint without one
