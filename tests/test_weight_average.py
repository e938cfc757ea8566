"""Weight averaging over a fit's late epochs (stochastic weight averaging), alone and inside Stage 2."""

import numpy as np
import torch

from lagsplat.chart import Chart
from lagsplat.io.clip import HELD_OUT, TRAIN
from lagsplat.train.averaging import WeightAverage
from lagsplat.train.stage2 import Stage2Config, train_stage2


def test_the_mean_is_over_the_offered_epochs_from_the_start_on():
    model = torch.nn.Linear(2, 1)
    avg = WeightAverage(start_epoch=2)
    seen = []
    for ep in range(5):
        with torch.no_grad():
            model.weight.fill_(float(ep))
            model.bias.fill_(-float(ep))
        if avg.offer(model, ep):
            seen.append(ep)
    assert seen == avg.epochs == [2, 3, 4]
    mean = avg.state_dict()
    assert torch.allclose(mean["weight"], torch.full((1, 2), 3.0)) and torch.allclose(mean["bias"], torch.full((1,), -3.0))
    assert model.weight.detach()[0, 0].item() == 4.0  # the trained model itself is left alone


def test_without_a_start_nothing_is_averaged():
    avg = WeightAverage(None)
    assert not avg.offer(torch.nn.Linear(1, 1), 10)
    assert avg.state_dict() is None and avg.epochs == []


def _oscillator_chart(n: int = 240, dt: float = 1 / 30) -> Chart:
    t = np.arange(n) * dt
    q = (np.exp(-0.05 * t) * np.cos(2 * np.pi * 0.8 * t))[:, None]
    split = np.where(np.arange(n) < int(0.75 * n), TRAIN, HELD_OUT).astype(np.int8)
    eye = np.eye(1)
    return Chart(mean=np.zeros(1), W=eye, W_inv=eye, q=q / q.std(), t=t, split=split, G_bar=eye, A=eye, ae_mse=np.zeros(n),
                 ae_floor_train=0.0, ae_floor_held_out=0.0, height=8, width=8)  # fmt: skip


def test_stage2_returns_the_mean_of_its_late_selection_snapshots():
    torch.set_num_threads(1)
    chart = _oscillator_chart()
    base = dict(epochs=10, windows_per_epoch=64, select_every=2, select_windows=4, hidden=(16, 16))
    plain_model, plain_hist = train_stage2(chart, Stage2Config(**base), seed=0, progress=False)
    model, hist = train_stage2(chart, Stage2Config(**base, average_from=0.5), seed=0, progress=False)
    # the same optimisation (same seed), only what is returned differs
    assert hist["select_nrmse"] == plain_hist["select_nrmse"] and hist["selected_epoch"] == plain_hist["selected_epoch"]
    assert hist["averaged_epochs"] == [5, 7, 9]
    assert hist["selected_nrmse"] == hist["averaged_nrmse"] and np.isfinite(hist["averaged_nrmse"])
    assert "averaged_epochs" not in plain_hist
    diff = [float((a - b).abs().max()) for a, b in zip(model.state_dict().values(), plain_model.state_dict().values())]
    assert max(diff) > 0  # the mean is not the selected epoch's weights
