"""The rollout figure (``figures/rollout.png``) on a tiny run folder written by hand.

No training: the viewer's hand-built pendulum (:func:`lagsplat.viewer.synthetic.synthetic_pendulum`)
gives the decoder, chart and Lagrangian; the clip is its own render. Everything is written
under pytest's ``tmp_path``.
"""

from __future__ import annotations

import json

import matplotlib.pyplot as plt
import numpy as np
import pytest
import torch

from lagsplat.artifacts import Artifacts
from lagsplat.chart import save_chart
from lagsplat.io.clip import HELD_OUT, Clip, save_clip
from lagsplat.models.autoencoder import AutoEncoder, save_stage1
from lagsplat.models.encoder import CpAEEncoder
from lagsplat.train.stage2 import PAPER_FIT, Stage2Config, save_stage2
from lagsplat.viewer.synthetic import synthetic_pendulum
from lagsplat.viz import rollout as rollout_viz

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _run_folder(root, metrics: dict):
    """A ``results/<system>``-like folder: clip, stage1, chart, stage2 and a ``metrics.json`` with ``metrics``."""
    torch.manual_seed(0)
    ae, chart, model = synthetic_pendulum(size=24, seconds=6.0, n_background=4)
    with torch.no_grad():
        rec = ae.decode(torch.as_tensor(chart.q, dtype=torch.float32)).permute(0, 2, 3, 1).numpy()
    images = np.clip(np.round(255 * rec), 0, 255).astype(np.uint8)
    d = root / "pendulum"
    save_clip(d / "clip.npz", Clip(images=images, t=chart.t, split=chart.split, meta={"source": "test"}))
    save_stage1(d / "stage1.pt", AutoEncoder(CpAEEncoder(1, (2, 2, 2), 12), ae.decoder, ae.height, ae.width), {"backend": "auto"}, {}, 1)
    save_chart(d / "chart.npz", chart)
    save_stage2(d / "stage2.pt", model, Stage2Config(hidden=(16, 16), learn_rest=False, **PAPER_FIT), {})
    (d / "metrics.json").write_text(json.dumps({"system": "pendulum", "metrics": metrics}))
    return Artifacts.at(d), chart


def test_rollout_figure_of_a_protocol_without_f_enc_segment_hz(tmp_path, monkeypatch) -> None:
    """The soft-robot protocol writes ``f_enc_hz`` but no ``f_enc_segment_hz`` (the figure used to raise KeyError).

    The figure is written and says in plain words what it shows: the axis label names the
    visibility share, the title the key metrics, and a marker the rollout's start time."""
    metrics = {
        "f_enc_hz": {"value": 0.8},
        "eps_freq": {"value": 0.0123},
        "eps_q": {"value": 0.051},
        "eps_I_over_AE": {"value": 2.5},
    }
    art, chart = _run_folder(tmp_path, metrics)
    figs = []
    close = plt.close
    monkeypatch.setattr(rollout_viz.plt, "close", lambda fig=None: (figs.append(fig), close(fig)))
    out = rollout_viz.rollout_figure(art, title="pendulum")
    assert out == art.rollout_figure == tmp_path / "pendulum" / "figures" / "rollout.png"
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 10_000

    ax = figs[0].axes[0]
    assert "q1" in ax.get_ylabel() and "% of the visibility" in ax.get_ylabel() and "tr G" not in ax.get_ylabel()
    assert ax.get_title() == "pendulum\neps_freq 1.23%, eps_q 0.051, eps_I / eps_AE 2.50  (held-out frames)"
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    start = [s for s in labels if s.startswith("rollout starts, t = ")]
    assert len(start) == 1
    # one natural period (1 / 0.8 Hz = 1.25 s) before the first held-out frame
    t_start = float(start[0].removeprefix("rollout starts, t = ").removesuffix(" s"))
    first_held_out = chart.t[np.flatnonzero(chart.split == HELD_OUT)[0]]
    assert t_start == pytest.approx(first_held_out - 1.25, abs=1.5 / 30)
    assert any(abs(line.get_xdata()[0] - t_start) < 0.01 for line in ax.get_lines() if line.get_linestyle() == "--")

    (art.metrics).write_text(json.dumps({"metrics": {"eps_q": {"value": 0.05}}}))
    with pytest.raises(ValueError, match="f_enc_segment_hz, f_enc_hz or f_modes_hz"):
        rollout_viz.rollout_figure(art)
