"""Stage 2's model selection rule and the potential's input-layer learning rate, and what they are for: an end stop
(a one-sided stiff spring, a kink in V) identified from its exact trajectory."""

from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from lagsplat import timeseries
from lagsplat.chart import Chart
from lagsplat.cli_common import plain
from lagsplat.dynamics.integrators import rollout
from lagsplat.io.clip import HELD_OUT, TRAIN
from lagsplat.train.stage2 import Stage2Config, _param_groups, selection_replaces, train_stage2, training_windows
ROOT = Path(__file__).resolve().parents[1]


def test_selection_keeps_the_last_finite_epoch_or_the_lowest_error():
    last, anywhere = Stage2Config(epochs=100, select_from=1.0), Stage2Config(epochs=100, select_from=0.0)
    assert selection_replaces(0.5, 0.1, 90, last)  # worse but later: the last epoch is kept
    assert not selection_replaces(float("nan"), 0.1, 90, last) and not selection_replaces(float("inf"), 0.1, 90, last)
    assert not selection_replaces(0.5, 0.1, 90, anywhere) and selection_replaces(0.05, 0.1, 90, anywhere)
    half = Stage2Config(epochs=100, select_from=0.5)
    assert selection_replaces(0.5, 0.1, 40, half) and not selection_replaces(0.5, 0.1, 60, half)


def test_a_clip_without_held_out_frames_selects_on_rollouts_from_several_phases():
    # 2.3 periods of 0.56 Hz at 30 fps (120 frames): four periods' horizon (214 frames) cannot fit, so by default one
    # rollout from the first frame spans the clip; with half the clip at most, the rollouts start at several frames
    t = np.arange(120) / 30.0
    q = np.cos(2 * np.pi * 0.56 * t)[:, None]
    I = np.eye(1)
    chart = Chart(mean=np.zeros(1), W=I, W_inv=I, q=q, t=t, split=np.full(len(t), TRAIN, np.int8), G_bar=I,
                  A=I, ae_mse=np.zeros(len(t)), ae_floor_train=0.0, ae_floor_held_out=0.0, height=8, width=8)  # fmt: skip
    whole = training_windows(chart, Stage2Config())
    assert list(whole.select_starts) == [0] and whole.select_horizon == 118
    half = training_windows(chart, Stage2Config(), select_share=0.5)
    assert half.select_horizon == 60
    assert len(set(half.select_starts.tolist())) > 4 and max(half.select_starts) + half.select_horizon <= len(t)


def test_the_potentials_input_layers_learn_faster():
    cfg = Stage2Config(lr=1e-3, lr_potential_input=10.0)
    model = cfg.build(2)
    groups = _param_groups(model, cfg)
    fast = {id(p) for p in model.potential_hat.g.inp.parameters()}
    assert [g["lr"] for g in groups] == [1e-3, pytest.approx(1e-2)]
    assert {id(p) for p in groups[1]["params"]} == fast
    assert sum(len(g["params"]) for g in groups) == len(list(model.parameters()))


def _exact_chart(q: np.ndarray, t: np.ndarray, train_fraction: float = 0.8) -> Chart:
    q = (q - q.mean(0)) / q.std(0)
    n = len(q)
    split = np.where(np.arange(n) < int(train_fraction * n), TRAIN, HELD_OUT).astype(np.int8)
    eye = np.eye(q.shape[1])
    return Chart(mean=np.zeros(q.shape[1]), W=eye, W_inv=eye, q=q, t=t, split=split, G_bar=eye, A=eye, ae_mse=np.zeros(n),
                 ae_floor_train=0.0, ae_floor_held_out=0.0, height=8, width=8)  # fmt: skip


def test_an_end_stop_is_identified_from_its_exact_trajectory():
    """A torsion disk whose swing hits a one-sided wall 15-30x as stiff as its spring: Stage 2 with fast input
    layers and the last epoch's model, on the exact angles, rolls the held-out part out at the true frequency
    within 5 % (the defaults miss it by about 10 %)."""
    from lagsplat.synth.realistic import clip_spec, motion_of

    m = motion_of(clip_spec("torsion_disk-end_stop-a60-128"))
    chart = _exact_chart(m.q[:, :1].astype(float), m.t)
    torch.set_num_threads(1)
    cfg = Stage2Config.from_mapping({**plain(OmegaConf.load(ROOT / "conf" / "config.yaml").stage2), "lr_potential_input": 10.0, "select_from": 1.0})
    model, hist = train_stage2(chart, cfg, seed=0, progress=False)
    assert hist["selected_epoch"] == cfg.epochs - 1
    ho = np.flatnonzero(chart.split == HELD_OUT)
    dt = float(np.median(np.diff(chart.t)))
    q0 = torch.tensor(chart.q[ho[:1]])
    v0 = torch.tensor((chart.q[ho[1:2]] - chart.q[ho[0] - 1 : ho[0]]) / (2 * dt))
    with torch.no_grad():
        pred = rollout(model, q0, v0, dt, len(ho))[0][0].numpy()
    f_true = timeseries.spectral_peak_frequency(chart.q[ho], dt)
    f_model = timeseries.spectral_peak_frequency(pred, dt)
    assert abs(f_model / f_true - 1) < 0.05, (f_model, f_true)
