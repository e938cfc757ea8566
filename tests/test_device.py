"""Training on a device (``device=auto|cpu|cuda``): the CPU is the reference; CUDA runs where there is one."""

from __future__ import annotations

import subprocess
import sys

import pytest
import torch

from lagsplat.train.device import resolve_device

needs_cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device here")


def test_resolve_device() -> None:
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    with pytest.raises(ValueError, match="expected auto, cpu or cuda"):
        resolve_device("gpu")
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="no CUDA device"):
            resolve_device("cuda")


def test_cli_rejects_a_bad_device_at_start_up(tmp_path) -> None:
    """The error names the key and the value and comes before any stage runs (nothing is written)."""
    r = subprocess.run(
        [sys.executable, "-m", "lagsplat", "ingest", "system=toy_tiny", f"results_dir={tmp_path}", "device=tpu"],
        capture_output=True, text=True, timeout=120,
    )
    assert r.returncode == 1
    assert "device=tpu: must be one of cpu, cuda, auto" in r.stderr  # the typed configuration, before any stage
    assert not any(tmp_path.iterdir())


@needs_cuda
def test_stage1_and_stage2_train_on_cuda_and_return_cpu_models() -> None:
    """A short Stage 1 on CUDA reconstructs as well as the CPU one (same seed and steps), and Stage 2 runs there."""
    from lagsplat.chart import build_chart
    from lagsplat.synth.pendulum import make_pendulum_clip
    from lagsplat.train.stage1 import Stage1Config, train_stage1
    from lagsplat.models.autoencoder import frames_to_tensor
    from lagsplat.train.stage2 import Stage2Config, train_stage2

    clip = make_pendulum_clip(size=(32, 32), duration_s=8.0)
    cfg = Stage1Config(n_gaussians=256, steps=300, batch=16, sigma_xy=0.05)
    errs = {}
    for dev in ("cpu", "cuda"):
        model, hist = train_stage1(clip, cfg, 1, seed=0, progress=False, device=dev)
        assert next(model.parameters()).device.type == "cpu"
        x = frames_to_tensor(clip.images[clip.train_idx][:32])
        with torch.no_grad():
            errs[dev] = float((model.decode(model.encode(x)) - x).abs().mean())
    assert errs["cuda"] < 1.5 * errs["cpu"] + 1e-3, errs
    chart = build_chart(model, clip, 16, 1e-3, 0)
    s2, _ = train_stage2(chart, Stage2Config.from_mapping({"epochs": 3}), progress=False, device="cuda")
    assert next(s2.parameters()).device.type == "cpu"


def _moving_scene_3d(T: int = 48, size: int = 24):
    """A tiny 3-D scene drawn by the 3-D decoder itself: a static backdrop of dots and a blob moving along world x
    with ``q = sin(t)``, seen by a main camera and two view cameras (clip, views)."""
    import numpy as np

    from lagsplat.io.clip import Clip
    from lagsplat.models.decoder3d import ConditionedGaussians3D
    from lagsplat.render.camera import look_at
    from lagsplat.views import ViewSet

    g = torch.Generator().manual_seed(0)
    cams = [look_at((x, 0.0, -2.5), (0.0, 0.0, 0.0), (0.0, -1.0, 0.0), size, size, 45.0) for x in (0.0, -0.8, 0.8)]
    n = 40
    dec = ConditionedGaussians3D(n + 1, 1, cams[0], depth_range=(1.5, 3.5), backend="torch")
    with torch.no_grad():
        mu = torch.cat([torch.rand(n, 2, generator=g) * 1.6 - 0.8, torch.full((n, 1), 0.6)], 1)
        dec.mu_raw.copy_(torch.cat([mu, torch.zeros(1, 3)]))
        dec.L_raw.copy_(dec._raw_diagonal(torch.ones(1), 0.08, n + 1))
        dec.L_raw[-1, 1] = 0.4  # the blob's world x follows q
        dec.mu_q.zero_()
        dec.logit_alpha.fill_(3.0)
        dec.logit_color.copy_(torch.randn(n + 1, 3, generator=g) * 2)
        t = np.arange(T) / 12.0
        q = torch.as_tensor(np.sin(2 * np.pi * 0.5 * t), dtype=torch.float32)[:, None]
        shots = [(dec.render(q, size, size, camera=c)[0].permute(0, 2, 3, 1).numpy() * 255).astype(np.uint8) for c in cams]
    split = (np.arange(T) >= int(0.75 * T)).astype(np.int8)
    return Clip(images=shots[0], t=t, split=split), ViewSet(np.stack(shots[1:], 1), cams, holdout=[])


@needs_cuda
def test_the_3d_decoder_trains_on_cuda_like_on_the_cpu() -> None:
    """Stage 1 with the 3-D decoder and cached views (projection, depth sorting, rendering through the view
    cameras, new primitives on the rig's plane-sweep depth) runs on CUDA and reconstructs the main view about
    as well as the CPU run of the same seed and steps; the model comes back on the CPU."""
    from lagsplat.models.autoencoder import frames_to_tensor
    from lagsplat.train.stage1 import Stage1Config, train_stage1

    clip, views = _moving_scene_3d()
    cfg = Stage1Config.from_mapping({"decoder": "conditioned3d", "n_gaussians": 96, "steps": 120, "batch": 8, "views_per_step": 2})
    errs = {}
    for dev in ("cpu", "cuda"):
        model, _ = train_stage1(clip, cfg, 1, seed=0, progress=False, device=dev, views=views)
        assert next(model.parameters()).device.type == "cpu"
        x = frames_to_tensor(clip.images[clip.train_idx][:16])
        with torch.no_grad():
            errs[dev] = float((model.decode(model.encode(x)) - x).abs().mean())
    assert errs["cuda"] < 1.5 * errs["cpu"] + 1e-3, errs
