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
