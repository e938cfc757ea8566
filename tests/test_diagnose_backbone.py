"""Backbone curves (lagsplat.diagnose.backbone): frequency and damping ratio against amplitude.

The video-side estimator is checked on trajectories of known ODEs integrated with scipy and sampled at 30 fps
with chart noise: a Duffing hardening spring against its first-order backbone, a Coulomb-friction oscillator
against its known loss per swing, a linear damped oscillator against its flat backbone. The model side is checked
on hand-built models (a linear oscillator, an untrained Stage-2 Lagrangian) and the report's wiring on a chart
diagnosed end to end.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from scipy.integrate import solve_ivp
from scipy.ndimage import gaussian_filter1d

from lagsplat.chart import Chart
from lagsplat.diagnose.backbone import local_backbone, model_backbone, trend
from lagsplat.diagnose.oscillator import LinearOscillator
from lagsplat.io.clip import HELD_OUT, TRAIN

pytestmark = pytest.mark.usefixtures("one_torch_thread")

DT = 1 / 30.0
F0 = 0.8  # Hz
W0 = 2 * math.pi * F0
NOISE = 2e-3  # chart noise, in units of the largest release amplitude (1)


def _record(accel, releases: tuple[float, ...] = (1.0, 0.6), seconds: float = 15.0, seed: int = 0) -> dict[str, np.ndarray]:
    """``local_backbone`` of free decays of ``qddot = accel(q, qdot)`` released at rest at ``releases`` (one run each),
    sampled at 30 fps, with white noise ``NOISE`` and the diagnosis's 1-frame smoothing."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, DT)
    p, runs = [], []
    for k, x0 in enumerate(releases):
        sol = solve_ivp(lambda _, y: [y[1], accel(y[0], y[1])], (0.0, seconds), [x0, 0.0], t_eval=t, method="DOP853", rtol=1e-10, atol=1e-12, max_step=DT / 4)
        x = sol.y[0] + NOISE * rng.standard_normal(len(t))
        p.append(gaussian_filter1d(x, 1.0, mode="nearest", truncate=6.0))
        runs.append(np.arange(len(t)) + k * len(t))
    tt = np.concatenate([t + k * (seconds + 1.0) for k in range(len(releases))])
    return local_backbone(np.concatenate(p), tt, runs, F0, min_amplitude=3 * NOISE, sigma=1.0)


def test_a_hardening_spring_reads_its_known_backbone() -> None:
    """Duffing ``qddot + 2 zeta w0 qdot + w0^2 q + kappa w0^2 q^3 = 0``: ``f(A) ~ f_d (1 + 3 kappa A^2 / 8)``.

    The first-order backbone neglects ``15 kappa^2 A^4 / 256`` (the Lindstedt series' next term, 0.23 % at
    ``kappa = 0.2``, ``A = 1``): each swing's frequency must sit within that plus its timing noise of the
    prediction, and the fitted change from the smallest to the largest amplitude within that plus 3 standard errors.
    """
    kappa, zeta = 0.2, 0.01
    r = _record(lambda q, v: -(W0**2) * q - kappa * W0**2 * q**3 - 2 * zeta * W0 * v)
    A, f = r["amplitude"], r["frequency_hz"]
    assert len(A) > 40 and A.max() > 0.9 and A.min() < 0.35  # two releases, decaying over the range
    fd = F0 * math.sqrt(1 - zeta**2)
    pred = fd * (1 + 3 * kappa * A**2 / 8)
    second = 15 * kappa**2 * A**4 / 256
    timing = 2 * NOISE / (A * W0 * 0.5 / F0)  # a turning point's time error ~ noise / (A w0) over a half period (1/(2 f))
    assert np.all(np.abs(f / pred - 1) <= second + 3 * timing + 1e-3)
    tr = trend(r, float(A.min()), float(A.max()))
    want = (1 + 3 * kappa * A.max() ** 2 / 8) / (1 + 3 * kappa * A.min() ** 2 / 8) - 1
    assert tr["f_change"] > 10 * tr["f_change_se"]  # rises, unmistakably
    assert abs(tr["f_change"] - want) <= 15 * kappa**2 / 256 + 3 * tr["f_change_se"]


def test_dry_friction_raises_the_damping_ratio_as_the_amplitude_falls() -> None:
    """Coulomb friction ``mu sign(qdot)`` (``Delta = mu / w0^2``) takes ``2 Delta`` off every swing, whatever its size:
    ``zeta ~ 2 Delta / (pi A)``, rising as the amplitude falls (1/A)."""
    delta = 0.02
    r = _record(lambda q, v: -(W0**2) * q - delta * W0**2 * np.tanh(v / 1e-3), releases=(1.0,), seconds=13.0)
    A, z = r["zeta_amplitude"], r["zeta"]
    assert len(z) >= 10 and A.max() / A.min() > 3
    # the known loss, 4 Delta a cycle: zeta pi A / (2 Delta) = 1, to the amplitude noise of the cycle's two swings
    # (sqrt(2) NOISE over its 4 Delta) and the log's next term, (4 Delta / A)^2 / 12 (1.3 % at the smallest swing)
    assert np.all(np.abs(z * math.pi * A / (2 * delta) - 1) <= 3 * math.sqrt(2) * NOISE / (4 * delta) + (4 * delta / A) ** 2 / 12 + 0.005)
    tr = trend(r, float(A.min()), float(A.max()))
    assert tr["zeta_lo"] > 2.5 * tr["zeta_hi"] and tr["zeta_lo"] - tr["zeta_hi"] > 5 * tr["zeta_change_se"]
    assert abs(tr["f_change"]) < 0.01  # the friction leaves the frequency alone


def test_viscous_damping_reads_flat() -> None:
    """A linear damped oscillator: ``zeta`` and the frequency do not change with the amplitude (within 3 standard
    errors), and the log decrement gives ``zeta`` itself."""
    zeta = 0.02
    r = _record(lambda q, v: -(W0**2) * q - 2 * zeta * W0 * v)
    tr = trend(r, float(r["amplitude"].min()), float(r["amplitude"].max()))
    assert abs(tr["zeta_lo"] - tr["zeta_hi"]) <= 3 * tr["zeta_change_se"] and abs(tr["zeta_lo"] - tr["zeta_hi"]) < 0.1 * zeta
    assert np.median(r["zeta"]) == pytest.approx(zeta, rel=0.05)
    assert abs(tr["f_change"]) <= 3 * tr["f_change_se"] + 1e-3
    assert np.median(r["frequency_hz"]) == pytest.approx(F0 * math.sqrt(1 - zeta**2), rel=2e-3)


def test_a_wide_smoothing_keeps_the_amplitudes_frequencies_and_damping() -> None:
    """Smoothing over 3 frames scales a 0.8 Hz swing by ``exp(-(2 pi f sigma dt)^2 / 2)`` (0.84): the amplitudes read
    through it, divided by that gain, are the raw decay's, and the frequency and zeta are unchanged."""
    zeta = 0.02
    t = np.arange(0.0, 12.0, DT)
    wd = W0 * math.sqrt(1 - zeta**2)
    x = np.exp(-zeta * W0 * t) * (np.cos(wd * t) + zeta / math.sqrt(1 - zeta**2) * np.sin(wd * t))  # released at rest
    raw = local_backbone(x, t, [np.arange(len(t))], F0, sigma=3.0)  # the same turning points (edges), unsmoothed...
    raw["amplitude"] = raw["amplitude"] * np.exp(-0.5 * (2 * math.pi * raw["frequency_hz"] * 3.0 * DT) ** 2)  # ...undo the gain
    wide = local_backbone(gaussian_filter1d(x, 3.0, mode="nearest", truncate=6.0), t, [np.arange(len(t))], F0, sigma=3.0)
    assert len(wide["amplitude"]) == len(raw["amplitude"]) >= 15
    assert np.allclose(wide["amplitude"], raw["amplitude"], rtol=2e-3)
    assert np.allclose(wide["frequency_hz"], F0 * math.sqrt(1 - zeta**2), rtol=1e-3)
    assert np.allclose(wide["zeta"], zeta, rtol=0.02)


def test_a_model_released_at_several_amplitudes_reads_its_own_backbone() -> None:
    """Free releases of a linear oscillator (rest off the origin, d = 2, released along one direction): flat, at its
    damped frequency (velocity Verlet at 30 fps runs ``(w h)^2 / 24`` fast, 0.12 %) and its damping ratio."""
    zeta, rest = 0.03, np.array([0.4, -0.2])
    K = np.diag([W0**2, (3 * W0) ** 2])
    model = LinearOscillator(K, np.diag([2 * zeta * W0, 2 * zeta * 3 * W0]), rest)
    amps = np.linspace(0.2, 1.0, 6)
    r = model_backbone(model, np.array([1.0, 0.0]), amps, DT, 300, F0, min_amplitude=0.1)
    assert set(np.unique(r["release"]).tolist()) == set(range(6))
    assert r["amplitude"].max() == pytest.approx(0.5 * (1 + math.exp(-math.pi * zeta)), rel=1e-3)  # the largest release's first swing
    assert np.all(np.abs(r["frequency_hz"] / (F0 * math.sqrt(1 - zeta**2)) - 1) < 4e-3)
    assert np.all(np.abs(r["zeta"] / zeta - 1) < 0.05)


def test_an_untrained_lagrangian_reads_its_linear_modes_at_small_amplitude() -> None:
    """A hand-built Stage-2 Lagrangian (scalar mass, ICNN potential, paper Eq. 7), rolled out on the compiled path:
    at small amplitude its swings read the linearised mode's frequency and damping ratio."""
    from lagsplat.dynamics.fast import supports_fast
    from lagsplat.models.lagrangian import Lagrangian

    torch.manual_seed(0)
    model = Lagrangian(1, "scalar").eval()
    model.init_energy_scales(omega=W0, zeta_floor=0.02)
    assert supports_fast(model)
    modes = model.modal_analysis()
    f_lin, z_lin = float(modes["f_hz"][0]), float(modes["zeta"][0])
    r = model_backbone(model, np.ones(1), np.array([0.01, 0.02]), DT, 200, f_lin)
    small = r["amplitude"] < 0.02
    assert small.sum() >= 6
    assert np.median(r["frequency_hz"][small]) == pytest.approx(f_lin * math.sqrt(1 - z_lin**2), rel=5e-3)
    assert np.median(r["zeta"][r["zeta_amplitude"] < 0.02]) == pytest.approx(z_lin, rel=0.1)


def _duffing_chart(n_train: int, seconds: float, gate_passed: bool = True) -> Chart:
    """A 1-D chart (identity whitening) of a hardening spring's decay with chart noise; frames past ``n_train`` held out."""
    t = np.arange(0.0, seconds, DT)
    sol = solve_ivp(lambda _, y: [y[1], -(W0**2) * y[0] - 0.3 * W0**2 * y[0] ** 3 - 2 * 0.01 * W0 * y[1]], (0.0, seconds), [1.0, 0.0],
                    t_eval=t, method="DOP853", rtol=1e-10, atol=1e-12, max_step=DT / 4)  # fmt: skip
    q = (sol.y[0] + NOISE * np.random.default_rng(1).standard_normal(len(t)))[:, None]
    split = np.where(np.arange(len(t)) < n_train, TRAIN, HELD_OUT).astype(np.int8)
    I = np.eye(1)
    return Chart(mean=np.zeros(1), W=I, W_inv=I, q=q, t=t, split=split, G_bar=I, A=I, ae_mse=np.zeros(len(t)), ae_floor_train=0.0,
                 ae_floor_held_out=0.0, height=8, width=8, meta={"gate": {"passed": gate_passed, "reasons": [] if gate_passed else ["coverage: test"]}})  # fmt: skip


def test_the_diagnosis_report_draws_and_reads_the_backbone(tmp_path) -> None:
    """``diagnose_artifacts`` writes ``figures/backbone.png``, lists it, keeps the readings in ``report.json`` and reads
    it in ``report.md``: the video hardens, a linear model fitted to it does not."""
    from lagsplat.diagnose import fit_linear_oscillator
    from lagsplat.diagnose.report import diagnose_artifacts

    chart = _duffing_chart(360, 18.0)
    model = fit_linear_oscillator([chart.q[:360]], DT)
    out = tmp_path / "diagnosis"
    rep = diagnose_artifacts(None, None, chart, model, None, out, system="duffing")
    on_disk = json.loads((out / "report.json").read_text())
    bb = on_disk["backbone"]
    assert bb["done"] and on_disk["figures"]["backbone"] == "figures/backbone.png"
    assert (out / "figures" / "backbone.png").stat().st_size > 10_000
    assert any(bb["video"]["held_out"]) and not all(bb["video"]["held_out"])  # every frame read, held-out ones marked
    assert len(bb["video"]["amplitude"]) == len(bb["video"]["frequency_hz"]) == len(bb["video"]["held_out"])
    video, lin = bb["trend"]["video"], bb["trend"]["identified model"]
    assert video["f_change"] > 0.05 and abs(lin["f_change"]) < 0.01  # hardening video, linear model
    rel = bb["models"]["identified model"]["release_amplitudes"]
    assert len(rel) == 6 and rel[0] == pytest.approx(bb["amplitude_range"][0])
    md = (out / "report.md").read_text()
    assert "backbone: [figures/backbone.png](figures/backbone.png): frequency and damping ratio against amplitude" in md
    assert "the recorded frequency rises" in md and "the identified model's" in md
    assert rep["backbone"]["reading"] == bb["reading"]
    assert on_disk["frames"]["held_out_used_for"].endswith("their swings are drawn in the backbone figure, which decides nothing")

    # a chart that fails its checks: drawn, and said to be no finding; a too-short one: skipped with the reason
    failed = diagnose_artifacts(None, None, _duffing_chart(360, 18.0, gate_passed=False), model, None, tmp_path / "failed", system="x")
    assert failed["verdict"] == "cannot_diagnose" and failed["backbone"]["done"]
    assert "a description, not a finding" in (tmp_path / "failed" / "report.md").read_text()


def test_too_few_swings_skip_the_backbone_with_the_reason(tmp_path) -> None:
    """Three swings: no backbone, no figure (an earlier run's removed), the reason in both reports."""
    from lagsplat.diagnose import fit_linear_oscillator
    from lagsplat.diagnose.report import diagnose_artifacts

    n = 240
    t = np.arange(n) * DT
    q = (np.exp(-3.5 * t) * np.cos(W0 * t) + NOISE * np.random.default_rng(0).standard_normal(n))[:, None]  # ~3 swings above the noise
    split = np.where(np.arange(n) < 150, TRAIN, HELD_OUT).astype(np.int8)
    I = np.eye(1)
    chart = Chart(mean=np.zeros(1), W=I, W_inv=I, q=q, t=t, split=split, G_bar=I, A=I, ae_mse=np.zeros(n),
                  ae_floor_train=0.0, ae_floor_held_out=0.0, height=8, width=8, meta={"gate": {"passed": True, "reasons": []}})  # fmt: skip
    out = tmp_path / "diagnosis"
    (out / "figures").mkdir(parents=True)
    (out / "figures" / "backbone.png").write_bytes(b"stale")
    rep = diagnose_artifacts(None, None, chart, fit_linear_oscillator([q], DT), None, out, system="short")
    assert not rep["backbone"]["done"] and "a backbone needs 4" in rep["backbone"]["reason"]
    assert "backbone" not in rep["figures"] and not (out / "figures" / "backbone.png").exists()
    assert "- backbone: not drawn: " in (out / "report.md").read_text()
