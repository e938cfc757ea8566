"""The model export (``python -m lagsplat export``) on tiny run folders written by hand, no training.

Two runs: the viewer's hand-built pendulum (d = 1, scalar inertia, convex potential, its rendered decoder) and a
random d = 2 model with every term the export handles (learned inertia, invex potential, one input channel,
a decoder with a static layer). Everything is written under pytest's temporary folders.
"""

from __future__ import annotations

import copy
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.integrate import solve_ivp

from lagsplat.artifacts import Artifacts
from lagsplat.chart import Chart, save_chart
from lagsplat.cli import main
from lagsplat.dynamics.fast import cached_export, fast_acceleration
from lagsplat.export import export_run
from lagsplat.export.splats import DEPTH_STEP_PX, N_SH_REST, PLY_FIELDS, THIN_PX, covariance_to_scale_rotation, read_ply_vertices, splats_at, write_splat_ply
from lagsplat.export.standalone_dynamics import Model
from lagsplat.export.tables import chart_velocity
from lagsplat.io.clip import HELD_OUT, TRAIN, Clip, save_clip
from lagsplat.models.autoencoder import AutoEncoder, save_stage1
from lagsplat.models.decoder import ConditionedGaussians
from lagsplat.models.decoder3d import ConditionedGaussians3D
from lagsplat.models.encoder import CpAEEncoder
from lagsplat.models.inertia import DecoderInertia
from lagsplat.render.camera import look_at
from lagsplat.train.stage2 import PAPER_FIT, Stage2Config, load_stage2, save_stage2
from lagsplat.viewer.synthetic import synthetic_pendulum

pytestmark = pytest.mark.usefixtures("one_torch_thread")

SITE = str(Path(np.__file__).resolve().parents[1])  # numpy's and scipy's folder, without the .pth files that put lagsplat on the path


def _pendulum_run(root: Path) -> Artifacts:
    """The synthetic pendulum's run folder (d = 1, scalar inertia) with a ``metrics.json``."""
    torch.manual_seed(0)
    ae, chart, model = synthetic_pendulum(size=24, seconds=3.0, n_background=3)
    d = root / "pendulum"
    images = np.zeros((len(chart.t), 24, 24, 3), np.uint8)
    save_clip(d / "clip.npz", Clip(images=images, t=chart.t, split=chart.split, meta={"source": {"file": "pendulum.mp4"}, "crop": [0, 0, 24, 24], "resize": [24, 24]}))
    save_stage1(d / "stage1.pt", AutoEncoder(CpAEEncoder(1, (2, 2, 2), 12), ae.decoder, ae.height, ae.width), {"backend": "auto"}, {}, 1)
    save_chart(d / "chart.npz", chart)
    save_stage2(d / "stage2.pt", model, Stage2Config(hidden=(16, 16), learn_rest=False, **PAPER_FIT), {"selected_epoch": 3})
    (d / "metrics.json").write_text(json.dumps({"metrics": {"f_modes_hz": {"value": [0.8], "units": "Hz", "definition": "modes"}}}))
    return Artifacts.at(d)


def _random_run(root: Path, mass: str = "learned") -> Artifacts:
    """A d = 2 run: random decoder with a static layer, a whitened chart with one input, a perturbed Lagrangian
    (``mass``, invex potential, one input channel)."""
    torch.manual_seed(1)
    rng = np.random.default_rng(1)
    H, W, K, n, dt = 12, 16, 24, 50, 1 / 25
    dec = ConditionedGaussians(K, 2, backdrop=(6, 8))
    with torch.no_grad():
        for p in (dec.mu_raw, dec.mu_q, dec.logit_alpha, dec.logit_color):
            p.copy_(torch.randn_like(p))
        dec.L_raw.copy_(0.5 * torch.randn_like(dec.L_raw))
        dec.set_backdrop(torch.rand(3, 6, 8))
    t = np.arange(n) * dt
    q = np.stack([0.8 * np.exp(-0.3 * t) * np.cos(7 * t), 0.5 * np.sin(4 * t)], 1) + 0.01 * rng.standard_normal((n, 2))
    Wm = np.array([[1.5, 0.3], [-0.2, 0.8]])
    split = (np.arange(n) >= 35).astype(np.int8)
    split[:2] = HELD_OUT  # the first training frame is not the first frame
    u = (0.5 + 0.5 * np.sin(2 * t))[:, None].astype(np.float32)
    chart = Chart(mean=np.array([0.1, -0.2]), W=Wm, W_inv=np.linalg.inv(Wm), q=q, t=t, split=split, G_bar=np.eye(2), A=np.eye(2),
                  ae_mse=np.zeros(n), ae_floor_train=0.0, ae_floor_held_out=0.0, height=H, width=W, u=u)  # fmt: skip
    d = root / f"random_{mass}"
    save_clip(d / "clip.npz", Clip(images=np.zeros((n, H, W, 3), np.uint8), t=t, u=u, u_names=["p1"], split=split, meta={"frames": [0, n]}))
    save_stage1(d / "stage1.pt", AutoEncoder(CpAEEncoder(2, (2, 2, 2), 12), dec, H, W), {"backend": "auto"}, {}, 2)
    save_chart(d / "chart.npz", chart)
    cfg = Stage2Config(hidden=(8, 8), mass=mass, potential="invex", sigma=1.0)
    inertia = DecoderInertia.from_decoder(dec, chart.W_inv, chart.mean, H, W) if mass == "decoder" else None
    model = cfg.build(2, 1, inertia)
    with torch.no_grad():
        for name, p in model.named_parameters():
            if p.requires_grad and name not in ("s_M", "s_V"):
                p.add_(0.2 * torch.randn_like(p))
    model.init_energy_scales(2 * math.pi * 1.2, 0.05)
    save_stage2(d / "stage2.pt", model.eval(), cfg, {})
    metrics = {"metrics": {"f_modes_hz": {"value": [1.1, 0.7], "units": "Hz"}, "zeta_modes": {"value": [0.05, 0.1], "units": "1"},
                           "free_intervals": {"value": [[3, 30]], "units": "frame"}, "eps_I": {"value": 0.1}}}  # fmt: skip
    (d / "metrics.json").write_text(json.dumps(metrics))
    return Artifacts.at(d)


@pytest.fixture(scope="module")
def random_export(tmp_path_factory):
    a = _random_run(tmp_path_factory.mktemp("export"))
    return a, export_run(a)


@pytest.fixture(scope="module")
def pendulum_export(tmp_path_factory):
    a = _pendulum_run(tmp_path_factory.mktemp("export"))
    return a, export_run(a)


def _fresh_process(code: str, cwd: Path) -> dict:
    """Run ``code`` in a new interpreter without ``site`` (so no editable install: lagsplat is not importable) and
    without ``PYTHONPATH``; NumPy and SciPy come from their own folder. Returns the JSON it prints."""
    head = f"import sys, json, importlib.util\nsys.path.append({SITE!r})\nsys.path.insert(0, {str(cwd)!r})\n"
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    r = subprocess.run([sys.executable, "-I", "-S", "-c", head + code], cwd=cwd, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout.strip().splitlines()[-1])


def _rows(path: Path) -> tuple[list[str], list[list[str]]]:
    lines = path.read_text().splitlines()
    return lines[0].split(","), [ln.split(",") for ln in lines[1:]]


def test_dynamics_py_alone_matches_lagsplat_in_a_fresh_process(random_export):
    """``dynamics.py`` imports neither lagsplat nor torch. Under a constant input, ``solve_ivp`` of its ``rhs``
    follows ``solve_ivp`` of lagsplat's compiled acceleration (what its rollouts use) to 1e-5, its ``rhs`` equals
    the Lagrangian's along the way, and its Verlet rollout is ``rollout.csv`` (lagsplat's rollout)."""
    a, files = random_export
    out = files["dynamics"].parent
    head, rows = _rows(out / "rollout.csv")
    roll = np.array([[float(v) for v in r] for r in rows])
    t, x0, h, u = roll[:, 0] - roll[0, 0], roll[0, 1:], float(roll[1, 0] - roll[0, 0]), 0.7
    code = f"""
assert importlib.util.find_spec('lagsplat') is None and 'lagsplat' not in sys.modules
import numpy as np
from scipy.integrate import solve_ivp
import dynamics
t, x0, u = np.array({t.tolist()!r}), np.array({x0.tolist()!r}), np.array([{u}])
sol = solve_ivp(dynamics.rhs, (0.0, t[-1]), x0, t_eval=t, args=(u,), method='DOP853', rtol=1e-10, atol=1e-12)
q, v = dynamics.rollout_verlet(x0[:2], x0[2:], {h!r}, len(t))
print(json.dumps({{'ivp': sol.y.T.tolist(), 'rhs': [dynamics.rhs(0.0, x, u).tolist() for x in sol.y.T],
                   'verlet': np.concatenate([q, v], 1).tolist(),
                   'foreign': sorted(m for m in sys.modules if m.split('.')[0] in ('lagsplat', 'torch'))}}))
"""
    res = _fresh_process(code, out)
    assert res["foreign"] == []
    model, _ = load_stage2(a.stage2)
    fm = cached_export(model)
    U = np.array([[u]])

    def f(_, x):
        return np.concatenate([x[2:], fast_acceleration(fm, x[None, :2], x[None, 2:], u=U)[0]])

    ref = solve_ivp(f, (0.0, t[-1]), x0, t_eval=t, method="DOP853", rtol=1e-10, atol=1e-12).y.T
    ivp = np.array(res["ivp"])
    assert np.ptp(ref[:, :2], 0).min() > 0.5  # it moves
    assert np.abs(ivp[:, :2] - ref[:, :2]).max() <= 1e-5
    md = copy.deepcopy(model).double()
    X = torch.as_tensor(ivp)
    qddot = md.acceleration(X[:, :2], X[:, 2:], u=torch.full((len(X), 1), u, dtype=torch.float64)).detach().numpy()
    assert np.allclose(np.array(res["rhs"])[:, 2:], qddot, rtol=1e-6, atol=1e-6 * np.abs(qddot).max())
    assert head == ["t", "q_1", "q_2", "qdot_1", "qdot_2"]
    assert np.abs(np.array(res["verlet"]) - roll[:, 1:]).max() <= 1e-9  # the free rollout, by the same scheme


def test_torchscript_terms_and_numpy_terms_equal_the_lagrangian(random_export):
    a, files = random_export
    model, _ = load_stage2(a.stage2)
    md = copy.deepcopy(model).double()
    q = torch.randn(9, 2, dtype=torch.float64)
    u = torch.rand(9, 1, dtype=torch.float64)
    ts = {k: torch.jit.load(str(files[k])) for k in ("M", "V", "C", "b")}
    with torch.no_grad():
        assert torch.allclose(ts["M"](q), md.mass_matrix(q), rtol=0, atol=1e-6)
        assert torch.allclose(ts["C"](q), md.dissipation_matrix(q), rtol=0, atol=1e-6)
        assert torch.allclose(ts["b"](q).transpose(1, 2) @ u[..., None], md.actuation_force(q, u)[..., None], rtol=0, atol=1e-6)
    assert torch.allclose(ts["V"](q), md.potential(q).detach(), rtol=0, atol=1e-6)
    np_model = Model(files["weights"])
    assert np_model.d == 2 and np_model.n_u == 1 and np_model.mass_kind == "learned"
    for i in range(len(q)):
        qi = q[i].numpy()
        assert np.allclose(np_model.mass_matrix(qi), md.mass_matrix(q[i : i + 1])[0].detach().numpy(), rtol=1e-6, atol=1e-6)
        assert np.allclose(np_model.potential(qi), float(md.potential(q[i : i + 1]).detach()), rtol=1e-6, atol=1e-6)
        assert np.allclose(np_model.input_map(qi).T @ u[i].numpy(), md.actuation_force(q[i : i + 1], u[i : i + 1])[0].detach().numpy(), atol=1e-6)
    with np.load(files["weights"]) as w:
        assert all(w[k].dtype == np.float64 for k in w.files if w[k].dtype.kind == "f")


def test_ply_files_hold_the_decoder_at_the_chart_states(random_export):
    from plyfile import PlyData

    a, files = random_export
    card = json.loads(files["model"].read_text())
    chart = a.load_chart()
    ae = a.load_stage1()
    assert [s["label"] for s in card["splats"]] == ["mean", "q_1=min", "q_1=max", "q_2=min", "q_2=max"]
    s = card["splats"][3]
    assert s["q"][1] == pytest.approx(chart.q[:, 1].min()) and s["q"][0] == pytest.approx(chart.q[:, 0].mean())
    ply = PlyData.read(str(files[s["file"]]))
    v = ply["vertex"].data
    assert v.dtype.names == PLY_FIELDS and len(v) == ae.decoder.K
    assert ply.text is False and ply.byte_order == "<"
    mine = read_ply_vertices(files[s["file"]])
    assert all(np.array_equal(mine[f], v[f]) for f in PLY_FIELDS)
    z = torch.as_tensor(np.array(s["q"]) @ chart.W_inv + chart.mean, dtype=torch.float32)[None]
    with torch.no_grad():
        means, gate, g = ae.decoder.condition(z)
        cov_px = ae.decoder.pixel_geometry(ae.height, ae.width)[1].double().numpy()
    scale = np.array([ae.width, ae.height])
    assert np.allclose(np.stack([v["x"], v["y"]], 1), means[0].numpy() * scale, atol=1e-4)
    # the decoder composites front to back in index order; a viewer sorts by depth, seen from z < 0 along +z
    assert np.array_equal(np.argsort(v["z"], kind="stable"), np.arange(len(v))) and np.all(np.diff(v["z"].astype(float)) > 0)
    assert np.allclose(v["z"], DEPTH_STEP_PX * np.arange(len(v)), atol=1e-5)
    assert np.allclose(np.stack([v["nx"], v["ny"], v["nz"]], 1), 0.0) and all(np.all(v[f"f_rest_{i}"] == 0) for i in range(N_SH_REST))
    assert np.allclose(1 / (1 + np.exp(-v["opacity"].astype(float))), np.clip((g.alpha * gate[0]).numpy(), 1e-6, 1 - 1e-6), atol=1e-5)
    rgb = 0.5 + 0.28209479177387814 * np.stack([v[f"f_dc_{i}"] for i in range(3)], 1)
    assert np.allclose(rgb, g.colors.numpy(), atol=1e-5)
    cov = _cov_of(v)
    assert np.allclose(cov[:, :2, :2], cov_px, rtol=1e-4, atol=1e-5 * np.abs(cov_px).max())
    assert np.allclose(cov[:, 2, 2], THIN_PX**2, rtol=1e-3)
    assert (files["backdrop"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n") and "backdrop.png" in card["files"]


def _cov_of(v) -> np.ndarray:
    """Covariances ``[K,3,3]`` of a 3DGS vertex table: ``R(q) diag(exp(s))^2 R(q)^T`` (the 3DGS renderer's rule)."""
    w, x, y, z = (v[f"rot_{i}"].astype(float) for i in range(4))
    nrm = np.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / nrm, x / nrm, y / nrm, z / nrm
    R = np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
                  np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
                  np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], 1)  # fmt: skip
    S = np.exp(np.stack([v[f"scale_{i}"].astype(float) for i in range(3)], 1))
    return R @ (S[:, :, None] ** 2 * np.swapaxes(R, 1, 2))


def test_principal_axes_rebuild_any_covariance_and_a_3d_decoder_exports_in_world_units(tmp_path):
    rng = np.random.default_rng(0)
    A = rng.standard_normal((200, 3, 3))
    cov = A @ np.swapaxes(A, 1, 2) + 1e-3 * np.eye(3)
    cov[:3] = np.diag([4.0, 1.0, 0.25])  # axis-aligned and
    cov[3] = np.diag([0.25, 1.0, 4.0])  # reversed: the quaternion's other branches
    std, quat = covariance_to_scale_rotation(cov)
    v = {f"rot_{i}": quat[:, i] for i in range(4)} | {f"scale_{i}": np.log(std[:, i]) for i in range(3)}
    assert np.allclose(_cov_of(v), cov, atol=1e-9) and np.allclose(np.linalg.norm(quat, axis=1), 1.0)

    dec = ConditionedGaussians3D(6, 1, look_at((0.0, 0.0, -2.0), (0.0, 0.0, 0.0), (0.0, -1.0, 0.0), 16, 16, 40.0))
    with torch.no_grad():
        dec.L_raw.copy_(0.3 * torch.randn_like(dec.L_raw))
        dec.mu_raw.copy_(torch.randn_like(dec.mu_raw))
    splats = splats_at(dec, np.array([0.4]), 16, 16)
    verts = read_ply_vertices(write_splat_ply(tmp_path / "s.ply", splats))
    with torch.no_grad():
        means, _, g = dec.condition(torch.tensor([[0.4]]))
    assert np.allclose(np.stack([verts["x"], verts["y"], verts["z"]], 1), means[0].numpy(), atol=1e-6)
    assert np.allclose(_cov_of(verts), g.cov.double().numpy(), rtol=1e-4, atol=1e-6)


def test_csv_tables_and_model_json(random_export):
    a, files = random_export
    chart = a.load_chart()
    head, rows = _rows(files["trajectory"])
    assert head == ["t", "q_1", "q_2", "qdot_1", "qdot_2", "u_1", "split"] and len(rows) == len(chart.t)
    table = np.array([[float(x) for x in r[:-1]] for r in rows])
    assert np.array_equal(table[:, 0], chart.t) and np.array_equal(table[:, 1:3], chart.q)
    assert [r[-1] for r in rows] == ["held_out" if s == HELD_OUT else "train" for s in chart.split]
    assert np.allclose(table[:, 3:5], chart_velocity(chart.q, 1 / 25, sigma=1.0)) and np.allclose(table[:, 5], chart.u[:, 0])
    _, roll = _rows(files["rollout"])
    first = int(np.flatnonzero(chart.split == TRAIN)[0])
    assert len(roll) == len(chart.t) - first and float(roll[0][0]) == pytest.approx(chart.t[first])
    seg = np.flatnonzero(chart.split == TRAIN)  # the rollout starts from the training segment, smoothed on its own
    assert float(roll[0][3]) == pytest.approx(chart_velocity(chart.q[seg], 1 / 25, sigma=1.0)[0, 0])

    card = json.loads(files["model"].read_text())
    assert card["d"] == 2 and card["n_u"] == 1 and card["u_names"] == ["p1"] and card["fps"] == pytest.approx(25.0)
    assert card["model"]["inertia"] == "learned" and card["model"]["potential"] == "invex"
    assert np.allclose(card["chart"]["W"], chart.W) and np.allclose(card["chart"]["mean"], chart.mean)
    assert card["identified"]["f_modes_hz"]["value"] == [1.1, 0.7] and "eps_I" not in card["identified"]
    assert card["intervals"] == {"free_intervals": {"value": [[3, 30]], "units": "frame"}}
    K = np.array(card["model"]["at_rest"]["K"])
    assert np.allclose(K, K.T, atol=1e-8) and np.linalg.eigvalsh(K).min() > 0  # V strongly convex at its minimum
    commit = card["provenance"]["code"]
    assert commit is None or len(commit["commit"]) == 40
    assert card["provenance"]["stage2"] == str(a.stage2) and card["provenance"]["frames"] == [0, 50]
    assert set(card["files"]) == {p.name for p in files.values()} | {"model.json"}


def test_chart_velocity_is_exact_for_a_quadratic_and_restarts_per_episode():
    t = np.arange(10) * 0.1
    q = np.stack([3 * t**2 - t, -t**2], 1)
    assert np.allclose(chart_velocity(q, 0.1), np.stack([6 * t - 1, -2 * t], 1))
    ep = (np.arange(10) >= 6).astype(int)
    v = chart_velocity(np.concatenate([q[:6], q[:4] + 5]), 0.1, ep)
    assert np.allclose(v[6:], v[:4]) and not np.allclose(v[5], v[6])


def test_the_cli_exports_the_pendulum_and_names_a_missing_checkpoint(pendulum_export, tmp_path, capsys):
    a, _ = pendulum_export
    card = json.loads((a.export / "model.json").read_text())
    assert card["model"]["inertia"] == "scalar" and "b.pt" not in card["files"] and not (a.export / "b.pt").exists()
    assert len(card["splats"]) == 3 and card["identified"]["f_modes_hz"]["value"] == [0.8]
    assert card["provenance"]["crop"] == [0, 0, 24, 24] and card["provenance"]["source"] == {"file": "pendulum.mp4"}
    root = a.system_dir.parent
    args = ["export", "system=toy", "system.name=pendulum", f"results_dir={root}", "threads=1", "progress=false"]
    assert main(args) == 0
    assert (a.model_dir / "config" / "export.yaml").exists() and "exported" in capsys.readouterr().out
    a.stage2.rename(tmp_path / "moved.pt")
    try:
        assert main(args) == 1
        err = capsys.readouterr().err
        assert f"{a.stage2}: not found" in err and "stage2" in err
    finally:
        (tmp_path / "moved.pt").rename(a.stage2)


def test_the_decoder_induced_inertia_is_refused_before_any_file_is_written(tmp_path):
    a = _random_run(tmp_path, mass="decoder")
    with pytest.raises(ValueError, match="mass='decoder'"):
        export_run(a)
    assert not a.export.exists()
