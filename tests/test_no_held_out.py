"""A clip too short for the held-out protocol, identified on all its frames and read in-sample;
and the diagnosis of a run an earlier stage stopped (a cannot_diagnose report with the stage's reason)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lagsplat.chart import Chart
from lagsplat.diagnose.oscillator import LinearOscillator
from lagsplat.evaluate import EvalConfig, evaluate
from lagsplat.evaluate.in_sample import HELD_OUT_METRICS
from lagsplat.io.clip import TRAIN, Clip, ClipError

ROOT = Path(__file__).resolve().parents[1]
NOTE = "no held-out validation (4.0 periods)"


def run(args: list[str], timeout: int = 900) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "lagsplat", *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout)


def _all_training(T: int, note: str | None, f: float = 0.8, zeta: float = 0.03, dt: float = 1 / 30) -> tuple[Clip, Chart]:
    """A damped oscillation at ``f`` Hz, ratio ``zeta``, every frame training; marked ``no_held_out`` when ``note``."""
    t = np.arange(T) * dt
    wn = 2 * math.pi * f / math.sqrt(1 - zeta**2)
    q = (np.exp(-zeta * wn * t) * np.cos(2 * math.pi * f * t))[:, None]
    split = np.full(T, TRAIN, np.int8)
    meta = {"split": {"kind": "contiguous", "train_fraction": 1.0, "n_train": T, "n_held_out": 0, **({"no_held_out": note} if note else {})}}
    clip = Clip(images=np.zeros((T, 8, 8, 3), np.uint8), t=t, split=split, meta=meta)
    chart = Chart(
        mean=np.zeros(1), W=np.eye(1), W_inv=np.eye(1), q=q, t=t, split=split, G_bar=np.eye(1), A=np.eye(1),
        ae_mse=np.full(T, 1e-4), ae_floor_train=1e-4, ae_floor_held_out=float("nan"), height=8, width=8,
    )  # fmt: skip
    return clip, chart


def test_check_length_accepts_a_clip_marked_for_in_sample_identification():
    from lagsplat.ingest import check_length

    clip, _ = _all_training(150, NOTE)
    assert clip.no_held_out == NOTE and check_length(clip, "short.mp4") is clip
    with pytest.raises(ClipError, match="no held-out frames"):  # the same split without the preparation's note
        check_length(_all_training(150, None)[0], "short.mp4")
    with pytest.raises(ClipError, match="15 training frames.*at least 20"):  # the training frames still need one window
        check_length(_all_training(15, NOTE)[0], "short.mp4")


def test_in_sample_metrics_of_a_known_damped_oscillator():
    """The model that generated the encoded motion reads its frequency and damping back in-sample; the held-out metrics are null."""
    f, zeta = 0.8, 0.03
    clip, chart = _all_training(150, NOTE, f, zeta)  # 5 s = 4 periods
    wn = 2 * math.pi * f / math.sqrt(1 - zeta**2)
    model = LinearOscillator(np.array([[wn**2]]), np.array([[2 * zeta * wn]]), np.zeros(1))
    m = evaluate(clip, None, chart, model, EvalConfig(), source="short.npz")
    for key in HELD_OUT_METRICS:
        assert m[key]["value"] is None and NOTE in m[key]["definition"], key
    assert abs(m["f_enc_hz"]["value"] - f) / f < 0.02
    assert m["eps_freq_in_sample"]["value"] < 0.01 and abs(m["f_sim_hz"]["value"] - f) / f < 0.02
    assert abs(m["zeta_enc"]["value"] - zeta) < 0.005 and abs(m["zeta_sim"]["value"] - zeta) < 0.005
    assert abs(m["zeta_modes"]["value"][0] - zeta) < 1e-6
    # a model twice as damped reads so, in-sample
    heavy = LinearOscillator(np.array([[wn**2]]), np.array([[4 * zeta * wn]]), np.zeros(1))
    assert abs(evaluate(clip, None, chart, heavy, EvalConfig())["zeta_sim"]["value"] - 2 * zeta) < 0.01
    # without the note, a clip with no held-out frames is still refused
    bare, chart = _all_training(150, None, f, zeta)
    with pytest.raises(ClipError, match="no held-out frames"):
        evaluate(bare, None, chart, model, EvalConfig(), source="short.npz")


def test_a_stop_record_is_cleared_by_its_stage_or_an_earlier_one(tmp_path):
    from lagsplat.artifacts import Artifacts
    from lagsplat.cli_common import clear_stop, compose, record_stop

    cfg = compose(["system=toy_tiny", f"results_dir={tmp_path}"])
    a = Artifacts.for_run(tmp_path, "toy_tiny")
    record_stop(cfg, "stage2", "the chart failed")
    assert a.load_stopped() == {**json.loads(a.stopped("stage2").read_text()), "path": str(a.stopped("stage2"))}
    assert a.load_stopped()["stage"] == "stage2" and a.load_stopped(upto="chart") is None
    assert not clear_stop(cfg, "evaluate") and a.load_stopped() is not None  # a later stage leaves it
    assert clear_stop(cfg, "stage1") and a.load_stopped() is None  # an earlier one undoes it
    record_stop(cfg, "ingest", "too short")
    assert not clear_stop(cfg, "stage1") and clear_stop(cfg, "ingest") and a.load_stopped() is None
    assert record_stop(cfg, "table", "not a pipeline stage") is None


def test_diagnose_after_a_refused_ingest_writes_a_cannot_diagnose_report(tmp_path):
    """1.5 s of the tiny toy is too short for the split: ingest stops; diagnose reports it and exits 0; a good ingest clears it."""
    common = ["system=toy_tiny", f"results_dir={tmp_path}", "progress=false", "threads=1"]
    r = run(["ingest", *common, "system.source.params.duration_s=1.5"])
    assert r.returncode == 1 and "too short" in r.stderr, r.stderr
    reason = r.stderr.strip().splitlines()[-1].split("error: ", 1)[1]
    stop = json.loads((tmp_path / "toy_tiny" / "stopped.json").read_text())
    assert stop["stage"] == "ingest" and stop["reason"] == reason and stop["time"]
    r = run(["diagnose", *common])
    assert r.returncode == 0, r.stderr
    rep = json.loads((tmp_path / "toy_tiny" / "diagnosis" / "report.json").read_text())
    from lagsplat.diagnose.report import CANNOT_DIAGNOSE

    assert rep["verdict"] == CANNOT_DIAGNOSE and rep["stopped"]["stage"] == "ingest" and reason in rep["verdict_text"]
    md = (tmp_path / "toy_tiny" / "diagnosis" / "report.md").read_text()
    assert "cannot diagnose: the ingest stage stopped" in md and reason in md
    r = run(["ingest", *common])
    assert r.returncode == 0 and not (tmp_path / "toy_tiny" / "stopped.json").exists(), r.stderr


@pytest.mark.slow
def test_a_short_clip_is_identified_on_all_its_frames(tmp_path):
    """The tiny toy cut to 7 s (5.6 periods), all training and marked no_held_out: Stage 2 trains on every frame,
    evaluate reads it in-sample, the rollout figure, the table and the diagnosis say so instead of failing."""
    from lagsplat.cli_common import compose, plain
    from lagsplat.io.clip import save_clip
    from lagsplat.synth import make_clip

    system = plain(compose(["system=toy_tiny"]).system)
    system["source"]["params"]["duration_s"] = 7.0
    clip = make_clip(system)
    clip.split[:] = TRAIN
    note = f"no held-out validation ({clip.n_frames * clip.dt * 0.8:.1f} periods)"
    clip.meta["split"] = {"kind": "contiguous", "train_fraction": 1.0, "n_train": clip.n_frames, "n_held_out": 0, "no_held_out": note}
    sysdir = tmp_path / "toy_tiny"
    save_clip(sysdir / "clip.npz", clip)
    common = ["system=toy_tiny", f"results_dir={tmp_path}", "progress=false", "threads=1", "stage1.steps=400", "stage1.n_gaussians=512", "stage1.retries=0"]
    for stage in ("stage1", "chart", "stage2", "evaluate", "figures"):
        r = run([stage, *common])
        assert r.returncode == 0, stage + r.stderr[-2000:]
    m = json.loads((sysdir / "metrics.json").read_text())
    assert m["held_out"] == note and m["n_held_out"] == 0 and m["chart_gate"]["passed"]
    for key in ("eps_freq", "eps_q", "eps_I_over_AE"):
        assert m["metrics"][key]["value"] is None and note in m["metrics"][key]["definition"]
    v = {k: e["value"] for k, e in m["metrics"].items()}
    assert abs(v["f_enc_hz"] - 0.8) < 0.04 and v["eps_freq_in_sample"] < 0.1 and 0 < v["zeta_enc"] < 0.1 and v["zeta_sim"] is not None
    assert (sysdir / "figures" / "rollout.png").stat().st_size > 10_000
    r = run(["table", *common, "table.systems=[toy_tiny]", "table.name=short"])
    assert r.returncode == 0, r.stderr
    tex = (tmp_path / "tables" / "short.tex").read_text()
    assert "& -- & -- & -- & --" in tex and note in tex and note in (tmp_path / "tables" / "short.csv").read_text()
    r = run(["diagnose", *common])
    assert r.returncode == 0 and note in r.stdout, r.stderr
    rep = json.loads((sysdir / "diagnosis" / "report.json").read_text())
    assert rep["held_out"] == note and rep["verdict"] != "cannot_diagnose" and rep["diagnosis"]["ranking"]
    assert rep["gap"]["before"] is None and not rep["refit"]["done"] and "held-out refit validation is skipped" in rep["refit"]["reason"]
    assert note[:1].upper() + note[1:] in (sysdir / "diagnosis" / "report.md").read_text()


def test_tables_print_the_held_out_metrics_of_an_in_sample_run_as_missing(tmp_path):
    """The paper table, the seed table and the ablation table read a metrics.json whose held-out metrics are null."""
    from lagsplat.report.tables import ablation_rows, physical_table, seed_table

    null = {"value": None, "definition": f"not measured: {NOTE}"}
    metrics = {k: null for k in HELD_OUT_METRICS} | {"f_sim_hz": {"value": 0.79}, "f_enc_hz": {"value": 0.8}, "f_modes_hz": {"value": [0.81]},
                                                     "zeta_modes": {"value": [0.02]}}  # fmt: skip
    p = tmp_path / "metrics.json"
    p.write_text(json.dumps({"title": "short clip", "d": 1, "provenance": "test", "held_out": NOTE, "stage2": {}, "metrics": metrics}))
    tex, csv = physical_table([p], tmp_path / "t.tex")
    assert "short clip & 1 & -- & -- & -- & -- \\\\ % " + NOTE in tex.read_text()
    assert csv.read_text().splitlines()[1].endswith(f",0.79,0.8,test,{NOTE}")
    md, _ = seed_table([p, p], [0, 1], tmp_path / "s.md")
    rows = md.read_text().splitlines()
    assert "| 0 | -- | -- | -- | -- | 0.7900 | 0.8000 |" in rows and "| **mean** |  |  |  |  | 0.7900 | 0.8000 |" in rows
    row = ablation_rows([p]).iloc[0]
    assert row.eps_q is None and row.f_modes_hz == "0.81"
