"""The CLI and the Snakemake DAG, run as a user would."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from lagsplat.chart import Chart
from lagsplat.evaluate import EvalConfig, evaluate
from lagsplat.io.clip import Clip, ClipError
from lagsplat.models.lagrangian import Lagrangian

ROOT = Path(__file__).resolve().parents[1]
SHARED_REAL = ROOT.parent / "shared" / "data" / "real"


def run(args: list[str], cwd: Path = ROOT, timeout: int = 900) -> subprocess.CompletedProcess:
    return subprocess.run(args, cwd=cwd, capture_output=True, text=True, timeout=timeout)


def test_cli_usage_and_unknown_stage():
    assert run([sys.executable, "-m", "lagsplat", "--help"]).returncode == 0
    r = run([sys.executable, "-m", "lagsplat", "nonsense", "system=toy"])
    assert r.returncode == 2 and "unknown stage" in r.stderr


def test_every_stage_prints_its_help(tmp_path):
    """``python -m lagsplat <stage> --help`` (or ``-h``) exits 0 with the stage's own usage, writing nothing."""
    from lagsplat.cli import STAGES, stage_help

    for stage in STAGES:
        text = stage_help(stage)
        assert text.startswith(f"usage: python -m lagsplat {stage} ") and f"\n  {stage} " in text, stage
    for stage, flag in (("diagnose", "--help"), ("stage1", "-h"), ("view", "--help")):
        r = run([sys.executable, "-m", "lagsplat", stage, flag, f"results_dir={tmp_path}"])
        assert r.returncode == 0 and r.stdout.startswith(f"usage: python -m lagsplat {stage} "), r.stderr
    assert not any(tmp_path.iterdir())


def test_cli_missing_source_is_one_clear_line(tmp_path):
    r = run([sys.executable, "-m", "lagsplat", "ingest", "system=oscillating_cart", f"raw_dir={tmp_path}", f"results_dir={tmp_path}/res"])
    assert r.returncode == 1
    lines = [ln for ln in r.stderr.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, r.stderr
    assert "oscillating_cart.webm" in lines[0] and "not found" in lines[0]
    assert not (tmp_path / "res" / "oscillating_cart" / "clip.npz").exists()


def test_cli_unknown_system_is_a_configuration_error(tmp_path):
    r = run([sys.executable, "-m", "lagsplat", "ingest", "system=no_such_system", f"results_dir={tmp_path}"])
    assert r.returncode == 1 and "no_such_system" in r.stderr


def test_download_offline_gives_one_line_and_leaves_nothing(tmp_path):
    # An unreachable URL stands in for "offline": the rule must say what to fetch and where.
    r = run(
        [
            sys.executable, "-m", "lagsplat", "download", "system=oscillating_cart", f"raw_dir={tmp_path}",
            "system.source.url=http://127.0.0.1:9/oscillatingCar.webm",
        ]
    )
    assert r.returncode == 1
    assert str(tmp_path / "oscillating_cart.webm") in r.stderr
    assert list(tmp_path.iterdir()) == []


def _chart_with_held_out(n_train: int, n_ho: int, f: float = 0.8, dt: float = 1 / 30) -> tuple[Clip, Chart]:
    T = n_train + n_ho
    t = np.arange(T) * dt
    q = np.sin(2 * math.pi * f * t)[:, None]
    split = (np.arange(T) >= n_train).astype(np.int8)
    clip = Clip(images=np.zeros((T, 8, 8, 3), np.uint8), t=t, split=split)
    chart = Chart(
        mean=np.zeros(1), W=np.eye(1), W_inv=np.eye(1), q=q, t=t, split=split, G_bar=np.eye(1), A=np.eye(1),
        ae_mse=np.full(T, 1e-4), ae_floor_train=1e-4, ae_floor_held_out=1e-4, height=8, width=8,
    )
    return clip, chart


def test_evaluate_refuses_a_held_out_segment_shorter_than_two_periods():
    clip, chart = _chart_with_held_out(200, 50)  # 50 frames = 1.7 s < two periods of 0.8 Hz (2.5 s)
    with pytest.raises(ClipError, match="two natural periods"):
        evaluate(clip, None, chart, Lagrangian(1), EvalConfig(), source="short.npz")


def test_snakemake_dry_run_of_the_whole_dag():
    raw = SHARED_REAL if SHARED_REAL.exists() else ROOT / "data" / "raw"
    r = run(["snakemake", "-n", "results/tables/physical.tex", "--config", f"raw_dir={raw}"])
    assert r.returncode == 0, r.stdout + r.stderr
    for rule in ("ingest", "stage1", "chart", "stage2", "evaluate", "figures", "table"):
        assert f"rule {rule}:" in r.stdout, rule
    for system in ("toy", "oscillating_cart", "red_apple_pendulum"):
        assert f"results/{system}/metrics.json" in r.stdout


def test_snakemake_dry_run_of_the_inertia_ablation():
    r = run(["snakemake", "-n", "-F", "results/tables/two_carts_inertia.tex"])
    assert r.returncode == 0, r.stdout + r.stderr
    for rule in ("ingest", "stage1", "chart", "stage2_variant", "evaluate_variant", "ablation_table"):
        assert f"rule {rule}:" in r.stdout, rule
    for v in ("mass_learned", "mass_decoder", "mass_constant"):
        assert f"results/two_carts/variants/{v}/metrics.json" in r.stdout


def test_snakemake_dry_run_of_the_inertia_ablation_over_seeds():
    # each variant's Stage 2 once per seed on the same frozen chart; the table job is told the seeds
    r = run(["snakemake", "-n", "-p", "-F", "results/tables/two_carts_inertia.tex", "--config", "ablation_seeds=0,2"])
    assert r.returncode == 0, r.stdout + r.stderr
    for v in ("mass_learned", "mass_decoder", "mass_constant"):
        for k in (0, 2):
            assert f"results/two_carts/variants/{v}@seed{k}/metrics.json" in r.stdout
            assert f"variant={v}@seed{k}" in r.stdout
    assert "'ablation_seeds=[0, 2]'" in r.stdout
    assert "variants/mass_decoder/metrics.json" not in r.stdout


def test_snakemake_dry_run_of_the_deformation_table(tmp_path):
    # paper App. B on the oscillating cart: the run's Stage 1 and chart, then the comparison stage
    res = tmp_path / "res"
    r = run(["snakemake", "-n", "-p", f"{res}/tables/deformation.tex", "--config", f"raw_dir={tmp_path}", f"results_dir={res}"])
    assert r.returncode == 0, r.stdout + r.stderr
    for rule in ("download", "ingest", "stage1", "chart", "deformation_table"):
        assert f"rule {rule}:" in r.stdout, rule
    assert "rule stage2:" not in r.stdout  # no force truth on the cart: its Stage 2 is not needed
    assert "python -m lagsplat deformation system=oscillating_cart" in r.stdout
    assert f"{res}/oscillating_cart/figures/deformation.png" in r.stdout


def test_snakemake_dry_run_plans_downloads_when_clips_are_absent(tmp_path):
    # an empty results folder too: with a trained results/oscillating_cart here, nothing would need the clip
    out = tmp_path / "results"
    r = run(["snakemake", "-n", f"{out}/tables/physical.tex", "--config", f"raw_dir={tmp_path}", f"results_dir={out}"])
    assert r.returncode == 0, r.stdout + r.stderr
    assert "rule download:" in r.stdout
    assert f"{tmp_path}/oscillating_cart.webm" in r.stdout and f"{tmp_path}/red_apple_pendulum.mov" in r.stdout


@pytest.mark.parametrize("system,file", [
    ("oscillating_cart", "oscillating_cart.webm"),
    ("red_apple_pendulum", "red_apple_pendulum.mov"),
    ("bouncing_cart", "bouncing_cart.mp4"),
])
def test_snakemake_dry_run_of_the_diagnosis_of_a_real_clip(tmp_path, system, file):
    res = tmp_path / "res"
    r = run(["snakemake", "-n", f"{res}/{system}/diagnosis/report.md", "--config", f"raw_dir={tmp_path}", f"results_dir={res}"])
    assert r.returncode == 0, r.stdout + r.stderr
    for rule in ("download", "ingest", "stage1", "chart", "stage2", "evaluate", "diagnose"):
        assert f"rule {rule}:" in r.stdout, rule
    assert f"{tmp_path}/{file}" in r.stdout


@pytest.mark.slow
def test_snakemake_end_to_end_on_the_tiny_toy(tmp_path):
    res = tmp_path / "results"
    r = run(["snakemake", "-c2", f"{res}/tables/smoke.tex", "--config", f"results_dir={res}"], timeout=1800)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    sysdir = res / "toy_tiny"
    for name in ("clip.npz", "stage1.pt", "chart.npz", "stage2.pt", "metrics.json", "figures/rollout.png", "config/stage1.yaml"):
        assert (sysdir / name).exists(), name
    m = json.loads((sysdir / "metrics.json").read_text())
    assert m["data"] == "synthetic"  # a procedural clip is not labelled real
    umask = os.umask(0o022)
    os.umask(umask)
    assert (sysdir / "metrics.json").stat().st_mode & 0o777 == 0o666 & ~umask  # the user's umask, not mkstemp's 0600
    for key in ("eps_freq", "eps_q", "eps_I", "eps_AE", "eps_I_over_AE", "f_sim_hz", "f_enc_hz", "f_truth_hz"):
        entry = m["metrics"][key]
        assert math.isfinite(entry["value"]) and entry["definition"], key
    # scikit-image's PSNR / SSIM of the same rollout frames: consistent with the image MSE (PSNR of the mean MSE
    # bounds the mean PSNR from below, Jensen), SSIM in (0, 1]
    psnr, ssim, eps_I = (m["metrics"][k]["value"] for k in ("psnr_db", "ssim", "eps_I"))
    assert 10 * math.log10(1 / eps_I) - 0.01 <= psnr < 10 * math.log10(1 / eps_I) + 10 and 0 < ssim <= 1
    # the encoded video oscillates at the generator's frequency even in this tiny run
    assert abs(m["metrics"]["f_enc_hz"]["value"] - m["metrics"]["f_truth_hz"]["value"]) / m["metrics"]["f_truth_hz"]["value"] < 0.05
    tex = (res / "tables" / "smoke.tex").read_text()
    assert "Pendulum (synthetic, tiny)" in tex and "\\toprule" in tex
    csv = (res / "tables" / "smoke.csv").read_text().splitlines()
    assert len(csv) == 2 and csv[0].startswith("system,d,eps_freq_pct")
    # re-running is a no-op: every artifact is up to date
    r2 = run(["snakemake", "-n", f"{res}/tables/smoke.tex", "--config", f"results_dir={res}"])
    assert "Nothing to be done" in r2.stdout + r2.stderr
    # the inertia ablation reuses the frozen chart: only stage2 / evaluate per variant run
    r3 = run(["snakemake", "-c2", f"{res}/tables/toy_tiny_inertia.tex", "--config", f"results_dir={res}"], timeout=1800)
    assert r3.returncode == 0, r3.stdout[-3000:] + r3.stderr[-3000:]
    assert "rule stage1:" not in r3.stdout + r3.stderr and "rule chart:" not in r3.stdout + r3.stderr
    import pandas as pd

    df = pd.read_csv(res / "tables" / "toy_tiny_inertia.csv")
    assert list(df["mass"]) == ["learned", "decoder", "constant"]
    assert np.isfinite(df["eps_q"]).all()
    for v in ("mass_learned", "mass_decoder", "mass_constant"):
        assert (sysdir / "variants" / v / "stage2.pt").exists()
        assert json.loads((sysdir / "variants" / v / "metrics.json").read_text())["stage2"]["mass"] == v.split("_")[1]
    # the force checks on the trained model, through both brushes
    r4 = run(["snakemake", "-c2", f"{res}/toy_tiny/forces.json", "--config", f"results_dir={res}"], timeout=900)
    assert r4.returncode == 0, r4.stdout[-3000:] + r4.stderr[-3000:]
    assert "rule stage1:" not in r4.stdout + r4.stderr
    fj = json.loads((sysdir / "forces.json").read_text())
    assert fj["brush"] == "visible" and set(fj["other_brushes"]) == {"paper"}
    for r in (fj, fj["other_brushes"]["paper"]):
        assert r["linearity"]["f_lat_rel_err"] < 1e-9 and r["kernel"]["rel"] < 1e-6
        assert r["background"]["on_object_median_dq"] > 0
    assert len(fj["lever"]["r_px"]) == len(fj["lever"]["f_lat"]) > 2 and (sysdir / "figures" / "forces.png").exists()
    # the extrapolation protocol with every baseline, at tiny budgets: LaGSplat, the neural ODE, GP-2D, and the
    # held-out frames themselves imported as "GaussianPrediction" frames (a perfect predictor)
    clip = np.load(sysdir / "clip.npz")
    ho = np.flatnonzero(clip["split"] == 1)
    pred_dir = tmp_path / "gp_frames"
    pred_dir.mkdir()
    rows = ["file,time_s"]
    for i in ho:
        cv2.imwrite(str(pred_dir / f"{i:05d}.png"), clip["images"][i][..., ::-1])
        rows.append(f"{i:05d}.png,{clip['t'][i]:.6f}")
    (pred_dir / "times.csv").write_text("\n".join(rows) + "\n")
    r5 = run([sys.executable, "-m", "lagsplat", "extrapolation", "system=toy_tiny", f"results_dir={res}", "gp2d.iterations=300",
              "gp2d.gcn_max_steps=60", "extrapolation.long_s=60", f"extrapolation.gaussian_prediction_frames={pred_dir}"], timeout=900)  # fmt: skip
    assert r5.returncode == 0, r5.stdout[-3000:] + r5.stderr[-3000:]
    xj = json.loads((sysdir / "extrapolation.json").read_text())
    assert set(xj["models"]) == {"lagsplat", "neural_ode", "gp2d", "gaussian_prediction"} and (sysdir / "figures" / "extrapolation.png").stat().st_size > 0
    gp, orig = xj["models"]["gp2d"], xj["models"]["gaussian_prediction"]
    assert math.isfinite(gp["psnr_fit_mean"]) and math.isfinite(gp["psnr_ae_floor_fit_mean"]) and 0 <= gp["encoded_in_range"] <= 1
    assert gp["gp2d_resolved"]["iterations"] == 300 and gp["n_fitted_frames"] == int(ho[0])
    assert orig["freq_error"] < 0.01 and orig["psnr_mean"] == math.inf and orig["amplitude_left"] is None  # the video itself
    assert xj["models"]["lagsplat"]["amplitude_left"] < 0.5
    # every job wrote its own log (the rule passes {log} to the CLI)
    for stage in ("ingest", "stage1", "chart", "stage2", "evaluate", "figures", "forces"):
        text = (res / "logs" / "toy_tiny" / f"{stage}.log").read_text()
        assert f"lagsplat {stage} system=toy_tiny: started" in text and "done in" in text, stage
    # the rollout figure of a run whose protocol writes no f_enc_segment_hz (the soft-robot protocol's
    # metrics.json has only f_enc_hz; this used to raise KeyError), through artifact overrides
    from lagsplat.artifacts import Artifacts
    from lagsplat.viz.rollout import rollout_figure

    alt = Artifacts.for_run(res, "toy_tiny", overrides={"metrics": tmp_path / "krauss_like.json", "rollout_figure": tmp_path / "fig.png"})
    alt.metrics.write_text(json.dumps(dict(m, metrics={k: v for k, v in m["metrics"].items() if k != "f_enc_segment_hz"})))
    assert rollout_figure(alt, title="soft-robot-like metrics") == alt.rollout_figure and alt.rollout_figure.stat().st_size > 10_000


def test_data_kind_of_each_system():
    """``metrics.json``'s ``data``: the system's own label, else synthetic for procedural sources, real for recordings."""
    from lagsplat.cli import compose
    from lagsplat.cli_common import data_kind

    kinds = {name: data_kind(compose([f"system={name}"]).system) for name in ("toy", "two_carts", "oscillating_cart", "krauss_2seg", "krauss_2seg_synth")}
    assert kinds == {"toy": "synthetic", "two_carts": "synthetic", "oscillating_cart": "real", "krauss_2seg": "real", "krauss_2seg_synth": "surrogate"}


def test_a_chart_that_fails_the_gate_stops_before_stage2_and_is_marked_when_forced(tmp_path):
    """Two Stage-1 steps draw no motion: the gate fails, Stage 2 refuses in one line (and the diagnosis reports that);
    chart.gate=false runs on and marks every metric."""
    base = [sys.executable, "-m", "lagsplat"]
    common = ["system=toy_tiny", f"results_dir={tmp_path}", "stage1.steps=2", "stage1.retries=0", "progress=false"]
    for stage in ("ingest", "stage1", "chart"):
        r = run(base + [stage] + common)
        assert r.returncode == 0, r.stderr
    assert "chart quality gate failed" in r.stdout
    r = run(base + ["stage2"] + common)
    lines = [ln for ln in r.stderr.strip().splitlines() if ln.strip()]
    assert r.returncode == 1 and len(lines) == 1, r.stderr
    assert "chart.npz" in lines[0] and "failed" in lines[0] and "Stage 2 not run" in lines[0]
    assert not (tmp_path / "toy_tiny" / "stage2.pt").exists()
    # the refusal is recorded; the diagnosis reports it (cannot_diagnose, the gate's reason) and exits 0
    reason = lines[0].split("error: ", 1)[1]
    assert json.loads((tmp_path / "toy_tiny" / "stopped.json").read_text())["stage"] == "stage2"
    r = run(base + ["diagnose"] + common)
    assert r.returncode == 0, r.stderr
    rep = json.loads((tmp_path / "toy_tiny" / "diagnosis" / "report.json").read_text())
    assert rep["verdict"] == "cannot_diagnose" and rep["stopped"]["reason"] == reason and "coverage" in rep["verdict_text"]
    assert reason in (tmp_path / "toy_tiny" / "diagnosis" / "report.md").read_text()
    for stage in ("stage2", "evaluate"):
        r = run(base + [stage] + common + ["chart.gate=false"])
        assert r.returncode == 0, r.stderr
    assert not (tmp_path / "toy_tiny" / "stopped.json").exists()  # Stage 2 ran: its stop no longer stands
    m = json.loads((tmp_path / "toy_tiny" / "metrics.json").read_text())
    assert m["read_on_failed_chart"] is True and m["chart_gate"]["passed"] is False
    assert all("caution" in e for e in m["metrics"].values())
