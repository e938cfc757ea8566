"""The published soft-robot protocol (lagsplat.evaluate.krauss) and the Table-4 builder (lagsplat.report.krauss).

Index conventions are checked against models whose rollouts are known in
closed form (zero acceleration, acceleration = pressure, a damped linear
oscillator), so a shifted frame, a different velocity stencil or a pressure
interpolated instead of held shows up as a non-zero error.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from lagsplat import timeseries
from lagsplat.chart import Chart
from lagsplat.evaluate.krauss import (
    DT_KRAUSS,
    KraussEvalConfig,
    ae_floor_frames,
    evaluate_krauss,
    flat_intervals,
    frequency_windows,
    leading_duplicates,
    mse_window_starts,
    multistep_mse,
    n_states,
    peak_frequency,
    rollout_zoh,
)
from lagsplat.io.clip import HELD_OUT, TRAIN, Clip
from lagsplat.report.krauss import krauss_rows, krauss_table, load_published

pytestmark = pytest.mark.usefixtures("one_torch_thread")
DT = DT_KRAUSS


class ZeroAccel:
    """``qddot = 0``: a rollout is exactly ``q0 + i dt v0``."""

    training = False

    def acceleration(self, q, qdot, f_ext=None, u=None):
        return torch.zeros_like(q)


class PressureAccel:
    """``qddot = u`` (``n_u = d``)."""

    training = False

    def acceleration(self, q, qdot, f_ext=None, u=None):
        return u.clone()


class Oscillator:
    """``qddot = -w^2 q - 2 zeta w qdot + B u`` per coordinate (``B = b I`` on the first ``d`` chambers)."""

    training = False

    def __init__(self, f_hz: float, zeta: float, b: float = 0.0) -> None:
        self.w, self.zeta, self.b = 2 * math.pi * f_hz, zeta, b

    def acceleration(self, q, qdot, f_ext=None, u=None):
        a = -self.w**2 * q - 2 * self.zeta * self.w * qdot
        if u is not None and self.b:
            a = a + self.b * u[:, : q.shape[1]]
        return a


class SingularAbove:
    """Zero acceleration, but the mass solve 'fails' for any window whose ``q[0] > 1``."""

    training = False

    def acceleration(self, q, qdot, f_ext=None, u=None):
        if (q[:, 0] > 1).any():
            raise torch.linalg.LinAlgError("singular mass matrix")
        return torch.zeros_like(q)


# --------------------------------------------------------------------------- §9.1 conventions
def test_published_window_draw_and_horizon():
    assert n_states(0.5, DT) == 30  # round(29.97)
    assert int(round(8.0 / DT)) == 480
    n = 10968  # two-segment validation clip
    s = mse_window_starts(n, 30, 480, 50, 0)
    assert np.array_equal(s, np.random.default_rng(0).integers(480, n - 30, 50))
    assert s.min() >= 480 and s.max() < n - 30
    with pytest.raises(ValueError, match="validation clip"):
        mse_window_starts(500, 30, 480)


def test_ae_floor_frames_linspace():
    idx = ae_floor_frames(10968, 480, 1000)
    assert len(idx) == 1000 and idx[0] == 480 and idx[-1] == 10967
    assert np.array_equal(idx, np.linspace(480, 10967, 1000).astype(np.int64))
    assert np.all(np.diff(idx) > 0)


def _linear_clip(n: int = 200, d: int = 2):
    t = np.arange(n) * DT
    return np.array([0.3, -0.2]) + np.outer(t, [1.5, -0.7])[:, :d]


def test_state_i_is_frame_s_plus_i_and_forward_difference_velocity():
    """Constant velocity, zero acceleration: the prediction is exact iff v0 is the 3-point forward
    difference (exact for a line) and state i is compared with frame s + i."""
    q = _linear_clip()
    cfg = KraussEvalConfig(skip_s=10 * DT)
    mse_q = lambda pred, tgt: ((pred - tgt) ** 2).mean(1)  # "frames" hold the true states
    ok = multistep_mse(q, q, None, ZeroAccel(), mse_q, DT, cfg)
    assert ok["horizon"] == 30 and len(ok["per_step"]) == 30 and ok["n_finite"] == 50
    assert np.array_equal(ok["starts"], np.random.default_rng(0).integers(10, 200 - 30, 50))
    assert ok["mse"] < 1e-9  # float32 rollout
    shifted = np.concatenate([q[1:], q[-1:]])  # frame s + i + 1 instead of s + i
    bad = multistep_mse(q, shifted, None, ZeroAccel(), mse_q, DT, cfg)
    assert bad["mse"] > 1e-5 and bad["per_step"][0] > 1e-5
    # the initial state is scored too: state 0 is q_smooth[s], equal to frame s for a line
    assert ok["per_step"][0] < 1e-9


def test_pressure_is_held_over_each_step():
    rng = np.random.default_rng(3)
    B, H, d = 4, 12, 2
    P = rng.uniform(0, 1, (B, H, d))
    q0, v0 = rng.normal(size=(B, d)), rng.normal(size=(B, d))
    out = rollout_zoh(PressureAccel(), q0, v0, DT, H, P)
    q, v = q0.copy(), v0.copy()
    for i in range(H - 1):  # both Verlet force evaluations see P[:, i]
        q, v = q + DT * v + 0.5 * DT**2 * P[:, i], v + DT * P[:, i]
        assert np.allclose(out[:, i + 1], q, atol=1e-5)
    # a frozen pressure [B, n_u] is the same as a constant schedule
    frozen = rollout_zoh(PressureAccel(), q0, v0, DT, H, P[:, 0])
    assert np.allclose(frozen, rollout_zoh(PressureAccel(), q0, v0, DT, H, np.repeat(P[:, :1], H, 1)), atol=1e-6)


def test_failed_solve_drops_only_that_window():
    q0 = np.array([[0.0, 0.0], [2.0, 0.0], [0.5, 0.0]])
    v0 = np.ones((3, 2))
    out = rollout_zoh(SingularAbove(), q0, v0, DT, 10, None)
    assert np.isnan(out[1, 1:]).all() and np.array_equal(out[1, 0], q0[1])
    ref = rollout_zoh(ZeroAccel(), q0[[0, 2]], v0[[0, 2]], DT, 10, None)
    assert np.allclose(out[[0, 2]], ref)


# --------------------------------------------------------------------------- §9.2
def test_flat_intervals_find_the_tail_and_plateaus():
    rng = np.random.default_rng(0)
    n = 2400
    P = rng.uniform(0.1, 0.9, (n, 4))  # driven: every frame moves by far more than 1 %
    P[1000:1300] = [0.5, 0.2, 0.3, 0.1]  # a 300-frame plateau
    P[1500:1550] = 0.4  # too short (< 120 frames)
    P[1700:1900] = 0.2 + np.linspace(0, 0.08, 200)[:, None]  # steps < 1 % each, drift > 5 %: discarded
    P[2000:] = 0.0  # depressurised tail, 400 frames
    got = flat_intervals(P, 480, 120)
    # frame t is flat when P[t+1] ~ P[t]: the plateau's last frame jumps to the next value
    assert got == [(2000, 2400), (1000, 1299)]
    assert flat_intervals(P, 480, 120, max_intervals=1) == [(2000, 2400)]
    assert flat_intervals(np.zeros((700, 2)), 480, 120) == [(480, 700)]  # constant after the head: all free
    assert flat_intervals(np.zeros((599, 2)), 480, 120) == []  # ... but shorter than 2 s
    with pytest.raises(ValueError, match="n_chambers"):
        flat_intervals(np.zeros(600), 480, 120)


def test_peak_frequency_recovers_a_known_frequency():
    f_true = 1.5016  # simulated two-segment frequency of the reference README
    n = int(round(8 / (1.5621 * DT)))  # an 8-period analysis window of the protocol
    t = np.arange(n) * DT
    x = np.exp(-0.1 * t) * np.cos(2 * math.pi * f_true * t + 0.3)
    f = peak_frequency(x, DT)
    assert abs(f - f_true) / f_true < 0.005
    q = np.stack([x, 0.5 * np.exp(-0.1 * t) * np.sin(2 * math.pi * f_true * t)], 1)
    assert abs(peak_frequency(q, DT, np.diag([2.0, 0.5])) - f_true) / f_true < 0.005


def test_peak_frequency_first_bin_above_the_cut_is_not_refined():
    n = 256
    df = 1 / (n * DT)
    t = np.arange(n) * DT
    x = np.cos(2 * math.pi * 2.3 * df * t)  # 2.3 cycles per window: peak in bin 2, lower neighbour cut
    assert peak_frequency(x, DT) == pytest.approx(2 * df, rel=1e-12)
    assert timeseries.spectral_peak_frequency(x, DT) != pytest.approx(2 * df, rel=1e-6)  # the generic estimator refines
    y = np.cos(2 * math.pi * 8.3 * df * t)
    assert peak_frequency(y, DT) == timeseries.spectral_peak_frequency(y, DT)


def test_leading_duplicates():
    rng = np.random.default_rng(1)
    fr = rng.integers(0, 256, (20, 4, 4, 3)).astype(np.uint8)
    assert leading_duplicates(fr) == 0
    fr[1] = fr[0]
    fr[2] = fr[0]
    assert leading_duplicates(fr) == 2


def _tail_clip(f_hz=1.5, zeta=0.02, n_drive=780, n_tail=700, seed=0):
    """Encoded trajectory: a driven part, then a free damped oscillation after the pressure drops to 0."""
    rng = np.random.default_rng(seed)
    n = n_drive + n_tail
    P = np.zeros((n, 4))
    P[:n_drive] = rng.uniform(0.1, 0.9, (n_drive, 4))
    w = 2 * math.pi * f_hz
    wd = w * math.sqrt(1 - zeta**2)
    t = np.arange(n_tail) * DT
    env = np.exp(-zeta * w * t)
    q = np.zeros((n, 2))
    q[:n_drive] = 0.5 * np.sin(np.arange(n_drive)[:, None] * [0.05, 0.031])
    q[n_drive:] = np.stack([env * np.cos(wd * t), 0.6 * env * np.sin(wd * t + 0.4)], 1)
    return q, P


def test_frequency_on_the_tail_matches_the_model():
    q, P = _tail_clip()
    G = np.eye(2)
    cfg = KraussEvalConfig()
    good = frequency_windows(q, P, P, G, Oscillator(1.5, 0.02), DT, cfg)
    assert good["intervals"][0] == (780, 1480)
    ok = [w for w in good["windows"] if w["status"] == "ok"]
    assert len(ok) >= 1 and all(w["length"] == round(8 / (1.5 * DT)) for w in ok)
    assert good["eps_freq"] < 0.01 and abs(good["f_enc_hz"] - 1.5) < 0.01
    off = frequency_windows(q, P, P, G, Oscillator(1.65, 0.02), DT, cfg)
    assert off["eps_freq"] == pytest.approx(0.10, abs=0.015)
    assert off["eps_freq_agg"] == pytest.approx(0.10, abs=0.015)


# --------------------------------------------------------------------------- the whole protocol, on fakes
class FakeAE:
    """A smooth decoder ``z [B,2] -> [B,3,8,8]`` in (0, 1)."""

    def __init__(self) -> None:
        g = torch.linspace(-1, 1, 8)
        self.Y, self.X = torch.meshgrid(g, g, indexing="ij")

    def decode(self, z):
        img = torch.sigmoid(z[:, 0, None, None] * self.X + z[:, 1, None, None] * self.Y)
        return torch.stack([img, 1 - img, 0.5 * img], 1)


def _fake_run(model_true, n_train=100, n_val=1400, n_tail=500, seed=0):
    rng = np.random.default_rng(seed)
    T = n_train + n_val
    P = np.zeros((T, 4))
    P[: T - n_tail] = np.repeat(rng.uniform(0, 1, (int(math.ceil((T - n_tail) / 20)), 4)), 20, 0)[: T - n_tail]
    q = rollout_zoh(model_true, np.zeros((1, 2)), np.zeros((1, 2)), DT, T, P[None, :-1])[0]
    ae = FakeAE()
    frames = (ae.decode(torch.as_tensor(q, dtype=torch.float32)).permute(0, 2, 3, 1).numpy() * 255).round().astype(np.uint8)
    split = np.full(T, TRAIN, np.int8)
    split[n_train:] = HELD_OUT
    t = np.arange(T) * DT
    clip = Clip(images=frames, t=t, u=P.astype(np.float32), u_names=["p1", "p2", "p3", "p4"], split=split, meta={})
    ae_mse = np.arange(T, dtype=float) * 1e-6
    chart = Chart(
        mean=np.zeros(2), W=np.eye(2), W_inv=np.eye(2), q=q, t=t, split=split, G_bar=np.diag([3.0, 1.0]), A=np.eye(2),
        ae_mse=ae_mse, ae_floor_train=0.0, ae_floor_held_out=0.0, height=8, width=8, u=P.astype(np.float32),
    )  # fmt: skip
    return clip, ae, chart


def test_evaluate_krauss_end_to_end_on_fakes():
    true = Oscillator(1.5, 0.03, b=2.0)
    clip, ae, chart = _fake_run(true)
    cfg = KraussEvalConfig(render_batch=256)
    truth = {"f_natural_hz": [1.5, 5.0], "zeta": [0.03, 0.03], "tail_start_frame": 1000}
    m = evaluate_krauss(clip, ae, chart, true, cfg, truth=truth)
    v = {k: e["value"] for k, e in m.items()}
    json.dumps(m)  # serialisable as it is written to metrics.json
    n = 1400
    assert v["ae_floor"] == pytest.approx(chart.ae_mse[100:][ae_floor_frames(n, 480)].mean())
    assert v["mse_window_starts"] == np.random.default_rng(0).integers(480, n - 30, 50).tolist()
    assert len(v["mse_0p5s_per_step"]) == 30 and v["n_diverged"] == 0
    assert v["free_intervals"][0] == [900, 1400]  # the tail, in validation frames
    assert v["eps_freq"] < 0.01 and v["f_truth_hz"] == pytest.approx(1.5 * math.sqrt(1 - 0.03**2))
    assert v["eps_freq_truth"] < 0.01 and v["eps_freq_enc_truth"] < 0.01
    assert v["tail_start_truth"] == 900
    assert v["eps_q"] < 0.2
    wrong = evaluate_krauss(clip, ae, chart, Oscillator(1.9, 0.03, b=2.0), cfg)
    assert wrong["mse_0p5s"]["value"] > 2 * v["mse_0p5s"] and wrong["eps_freq"]["value"] > 0.2
    assert "f_truth_hz" not in wrong


def test_the_inputs_share_near_a_mode_reads_the_spectrum_of_the_training_pressures():
    from lagsplat.evaluate.krauss import _input_share_near

    T = 1200
    t = np.arange(T) * DT
    u = np.stack([np.sin(2 * math.pi * 1.5 * t), 0.1 * np.sin(2 * math.pi * 6.0 * t)], 1).astype(np.float32)
    split = np.full(T, TRAIN, np.int8)
    split[1000:] = HELD_OUT
    chart = Chart(mean=np.zeros(1), W=np.eye(1), W_inv=np.eye(1), q=np.zeros((T, 1)), t=t, split=split, G_bar=np.eye(1), A=np.eye(1),
                  ae_mse=np.zeros(T), ae_floor_train=0.0, ae_floor_held_out=0.0, height=8, width=8, u=u)  # fmt: skip
    assert _input_share_near(chart, DT, 1.5) > 0.95
    assert 0.005 < _input_share_near(chart, DT, 6.0) < 0.02  # (0.1)^2 of the power
    assert _input_share_near(chart, DT, 3.5) < 1e-3


# --------------------------------------------------------------------------- Table 4
def _metrics(path, system, data="real", variant=None, mass="learned", **vals):
    base = {"mse_0p5s": 7.7e-4, "ae_floor": 6.3e-5, "eps_freq": 0.057, "eps_q": 0.3, "f_enc_hz": 1.56, "f_sim_hz": 1.5,
            "mse_0p5s_sem": 1e-5, "freq_windows": [{"status": "ok"}]}  # fmt: skip
    base.update(vals)
    path.parent.mkdir(parents=True, exist_ok=True)
    doc = {"system": system, "variant": variant, "d": 4, "data": data, "protocol": "krauss", "stage2": {"mass": mass},
           "metrics": {k: {"value": x} for k, x in base.items()}}  # fmt: skip
    path.write_text(json.dumps(doc))
    return path


def test_published_csv_is_packaged_and_sourced():
    pub = load_published()
    assert len(pub) >= 10 and pub["source"].str.len().min() > 10
    two = pub[(pub.block == "two_segments") & (pub.method == "Koopman + ABCD")].iloc[0]
    assert (two["d"], two["ae_1e-5"], two["mse_1e-3"], two["eps_freq_pct"]) == (10, 5.17, 0.984, 8.3)
    assert "Table 4" in two["source"]
    const = pub[pub.method == "LaGSplat, constant M (paper)"].iloc[0]
    assert math.isnan(const["eps_freq_pct"]) and math.isnan(const["ae_1e-5"])  # not published: left empty


def test_table_rows_from_metrics_and_missing_runs_absent(tmp_path):
    res = tmp_path / "results"
    two = _metrics(res / "krauss_2seg" / "metrics.json", "krauss_2seg")
    dec = _metrics(res / "krauss_2seg" / "variants" / "mass_decoder" / "metrics.json", "krauss_2seg", variant="mass_decoder", mass="decoder", mse_0p5s=1.2e-3)
    missing = res / "krauss_2seg" / "variants" / "mass_constant" / "metrics.json"
    tex, csv, md = krauss_table(res / "krauss_1seg" / "metrics.json", two, [dec, missing], res / "tables" / "krauss.tex")
    import pandas as pd

    df = pd.read_csv(csv)
    ours = df[df.origin == "this run"]
    assert list(ours.method) == ["LaGSplat (this run)", "LaGSplat, decoder-induced M (this run)"]
    assert list(ours.block) == ["two_segments", "inertia_ablation"]
    assert ours.iloc[0]["mse_1e-3"] == pytest.approx(0.77) and ours.iloc[0]["ae_1e-5"] == pytest.approx(6.3)
    assert ours.iloc[0]["eps_freq_pct"] == pytest.approx(5.7)
    assert not (df.origin == "this run").any() or "one_segment" not in set(ours.block)  # no 1-seg run: no row
    pub = df[df.origin == "published"]
    assert len(pub) == len(load_published()) and pub.source.notna().all()
    text = tex.read_text()
    assert r"\textbf{LaGSplat} (this run) & nonlin.\ & $4$ & $6.3$ & $0.77$ & $5.7$ & $\checkmark$" in text
    assert "constant $M$ (this run)" not in text and r"\dagger" not in text
    assert "| LaGSplat (this run) | nonlin. | 4 | 6.3 | 0.77 | 5.7 | ✓ | real | this run |" in md.read_text()


def test_surrogate_rows_are_labelled(tmp_path):
    two = _metrics(tmp_path / "krauss_2seg_synth" / "metrics.json", "krauss_2seg_synth", data="surrogate",
                   mse_0p5s=1e-4, f_truth_hz=1.546, eps_freq_truth=0.02, eps_freq_enc_truth=0.01)  # fmt: skip
    df = krauss_rows(None, two, [])
    row = df[df.origin == "this run"].iloc[0]
    assert row["data"] == "surrogate" and row["eps_freq_truth_pct"] == pytest.approx(2.0)
    tex, _, md = krauss_table(None, two, [], tmp_path / "t" / "krauss.tex")
    text = tex.read_text()
    assert r"\textbf{LaGSplat} (this run)$^\dagger$" in text and "simulated surrogate" in text
    assert r"\mathbf{0.1}" not in text  # a surrogate number is never bolded against the published rows
    md_text = md.read_text()
    assert "eps_freq vs simulator (%)" in md_text
    assert "| LaGSplat (this run) | nonlin. | 4 | 6.3 | 0.1 | 5.7 | 2.0 | 1.00 | ✓ | surrogate | this run |" in md_text


def test_table_refuses_other_metrics_and_bad_csv(tmp_path):
    other = tmp_path / "m.json"
    other.write_text(json.dumps({"system": "toy", "d": 1, "metrics": {"eps_q": {"value": 0.1}}}))
    with pytest.raises(ValueError, match="protocol=krauss"):
        krauss_rows(None, other, [])
    bad = tmp_path / "pub.csv"
    bad.write_text("block,method,dynamics,d,ae_1e-5,mse_1e-3,eps_freq_pct,ext_force,data,source\none_segment,X,lin.,6,1,1,1,telepathy,real,paper\n")
    with pytest.raises(ValueError, match="ext_force"):
        load_published(bad)


def test_an_ablation_variant_over_seeds_gives_its_median_row(tmp_path):
    res = tmp_path / "results"
    two = _metrics(res / "krauss_2seg" / "metrics.json", "krauss_2seg")
    runs = [_metrics(res / "krauss_2seg" / "variants" / f"mass_decoder@seed{k}" / "metrics.json", "krauss_2seg", variant=f"mass_decoder@seed{k}",
                     mass="decoder", mse_0p5s=m, eps_freq=e) for k, (m, e) in enumerate([(1.0e-3, 0.09), (3.0e-3, 0.02), (2.0e-3, 0.05)])]
    absent = res / "krauss_2seg" / "variants" / "mass_decoder@seed3" / "metrics.json"  # a seed not run: left out of the median
    tex, csv, _ = krauss_table(None, two, [[*runs, absent]], res / "tables" / "krauss.tex")
    import pandas as pd

    abl = pd.read_csv(csv).query("block == 'inertia_ablation' and origin == 'this run'")
    assert len(abl) == 1
    r = abl.iloc[0]
    assert r.method == "LaGSplat, decoder-induced M, median of 3 seeds (this run)" and r.seeds == 3
    assert (r["mse_1e-3"], r["eps_freq_pct"]) == (pytest.approx(2.0), pytest.approx(5.0))
    assert "median of 3 seeds" in tex.read_text()
