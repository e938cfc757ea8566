"""Forces in three dimensions against a known truth: the 3-D pendulum pushed at its bob.

The model is one trained on the 3-D pendulum's *free* motion from the main camera and its cached views
(``results/pendulum3d``: ``snakemake -c2 results/pendulum3d/metrics.json``). The truth
(:mod:`lagsplat.synth.pendulum3d`): a point-mass pendulum of length ``L`` hinged at ``PIVOT`` and swinging
in a vertical plane turned 45 degrees from the main camera's image plane, its bob at
``PIVOT + L (sin theta d - cos theta z)`` (``d`` the swing's horizontal direction, ``z`` up). A static world
force ``F`` on the bob, in units of its weight ``m g``, holds it at

    tan theta = (F . d) / (1 - F . z),

and moves the bob by ``L (sin theta d + (1 - cos theta) z)`` metres. The model predicts the same
displacement as ``p(q_eq) - p(q_rest)``: the application point of the material the main camera's ray
through the bob's pixel meets first (:meth:`lagsplat.forces.transport3d.ForceTransport3D.select`), ``q_eq`` the loaded
equilibrium under ``kappa sum_i w_i J_i^T F`` (paper Eq. 9 with ``J_i [3,d]``, §4.5). ``kappa`` is
calibrated on the first force (in the image plane) only; the others, pushes and pulls along the main
camera's optical axis among them, are compared by the direction (degrees) and magnitude (%) of the
displacement in world space.

A 2-D model of the same clip receives a force as a 2-D vector in the image: the projection ``P F`` of a
world force at the bob (``P = d uv / d X``, pixels per metre). The last lines give, per force, that
image-plane part against the image-plane calibration force's: a push along the line of sight through the
bob projects to nothing, so no 2-D model can express it, while it turns the true pendulum.

    python benchmarks/force_truth3d.py [--results results/pendulum3d] [--sigma 1.0] [--min-transmittance 0.5]

Prints the table and writes it to ``results/benchmarks/force_truth3d.md`` (``--report PATH``, ``--no-report``);
no assertion (scores, not tests).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing
from _common import Report, add_report_options, env_header, shown_path

ROOT = Path(__file__).resolve().parents[1]


def _parse(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--results", type=Path, default=ROOT / "results" / "pendulum3d", help="trained 3-D pendulum folder")
    ap.add_argument("--sigma", type=float, default=1.0, help="brush spacing, pixels")
    ap.add_argument("--min-transmittance", type=float, default=0.5, help="front-surface threshold of the selection")
    add_report_options(ap, "force_truth3d")
    return ap.parse_args(argv)


def true_displacement(F, L: float):
    """The bob's static displacement (m, ``[3]``) and angle (rad) under the world force ``F [3]`` (units of ``m g``)."""
    import numpy as np

    from lagsplat.synth.pendulum3d import swing_axes

    d, _ = swing_axes()
    z = np.array([0.0, 0.0, 1.0])
    theta = math.atan2(float(F @ d), 1.0 - float(F @ z))
    return L * (math.sin(theta) * d + (1.0 - math.cos(theta)) * z), theta


def main(argv: list[str] | None = None):
    args = _parse(argv)
    import numpy as np
    import torch

    from lagsplat.artifacts import Artifacts
    from lagsplat.forces.transport import calibrate_kappa
    from lagsplat.forces.transport3d import ForceTransport3D
    from lagsplat.render.camera import project_points
    from lagsplat.synth.pendulum3d import PIVOT, ROD_M

    a = Artifacts.at(args.results)
    if not all(p.exists() for p in (a.stage1, a.chart, a.stage2)):
        raise SystemExit(f"{shown_path(args.results)}: no trained 3-D pendulum (snakemake -c2 results/pendulum3d/metrics.json makes one)")
    ae, chart = a.load_stage1(), a.load_chart()
    model, _ = a.load_stage2()
    ft = ForceTransport3D.from_autoencoder(ae, chart, min_transmittance=args.min_transmittance)
    cam = ae.decoder.camera
    R = np.asarray(cam.R, float)
    axis, right = R[2], R[0]  # the main camera's optical axis (away from it) and image x, world
    q_rest = model.loaded_equilibrium(None).float()
    bob = np.asarray(PIVOT) - np.array([0.0, 0.0, ROD_M])
    X = torch.tensor(bob[None], dtype=torch.float32, requires_grad=True)
    uv = project_points(X, cam)[0][0]
    P = np.stack([torch.autograd.grad(uv[k], X, retain_graph=True)[0][0].numpy() for k in range(2)])  # [2,3] px per m
    uv = uv.detach()
    sel = ft.select(q_rest, cam, uv, sigma=args.sigma)
    if float(sel.weights.sum()) == 0:
        raise SystemExit(f"{shown_path(args.results)}: the main camera's ray through the bob's pixel {uv.tolist()} meets no material")
    ray = ft.viewing_direction(cam, uv).numpy().astype(float)
    forces = [("image x (calibration)", 0.15 * right), ("optical axis, push", 0.15 * axis), ("optical axis, pull", -0.15 * axis),
              ("optical axis, push x2", 0.30 * axis), ("line of sight, push", 0.15 * ray), ("image x, opposite", -0.15 * right),
              ("image x + optical axis", 0.10 * right + 0.10 * axis)]  # fmt: skip
    true0, _ = true_displacement(forces[0][1], ROD_M)
    kappa = calibrate_kappa(model, ft, sel, torch.tensor(forces[0][1][None], dtype=torch.float32), float(np.linalg.norm(true0)), q_rest)
    p0 = ft.application_point(q_rest, sel)[0].detach().numpy()

    rep = Report("Forces in 3-D against a known truth (3-D pendulum)", args.report, __file__, argv)
    print(env_header("numba not used"))
    rep.text(
        f"model: {shown_path(args.results)} ({ae.width}x{ae.height} px, {ae.decoder.K} Gaussians, d = {model.d}); bob pixel at rest "
        f"({uv[0]:.1f}, {uv[1]:.1f}); brush sigma {args.sigma} px, min transmittance {args.min_transmittance}; kappa {kappa:.4g} "
        f"(calibrated on force 0); forces in units of the bob's weight; optical axis ({axis[0]:+.3f}, {axis[1]:+.3f}, {axis[2]:+.3f})"
    )
    rows, scored = [], []
    for k, (name, F) in enumerate(forces):
        true, theta = true_displacement(F, ROD_M)
        q_eq = model.loaded_equilibrium(ft.pullback(sel, torch.tensor(F[None], dtype=torch.float32), kappa), q0=q_rest)
        disp = ft.application_point(q_eq.float(), sel)[0].detach().numpy() - p0
        cos = float(disp @ true / (np.linalg.norm(disp) * np.linalg.norm(true) + 1e-12))
        dir_err = math.degrees(math.acos(max(-1.0, min(1.0, cos))))
        mag_err = 100.0 * (np.linalg.norm(disp) / np.linalg.norm(true) - 1.0)
        img = float(np.linalg.norm(P @ F) / np.linalg.norm(P @ forces[0][1]))
        if k:
            scored.append((name, dir_err, mag_err))
        rows.append({"#": f"{k}" + (" (calibration)" if k == 0 else ""), "force": name, "F (world, m g)": "(" + ", ".join(f"{v:+.3f}" for v in F) + ")",
                     "true angle (deg)": f"{math.degrees(theta):+.2f}", "true disp (mm)": "(" + ", ".join(f"{1e3 * v:+.1f}" for v in true) + ")",
                     "model disp (mm)": "(" + ", ".join(f"{1e3 * v:+.1f}" for v in disp) + ")", "dir err (deg)": f"{dir_err:.1f}",
                     "mag err (%)": f"{mag_err:+.1f}", "true depth change (mm)": f"{1e3 * float(true @ axis):+.1f}",
                     "image-plane part / calibration's": f"{img:.3f}"})  # fmt: skip
    rep.table(rows)
    within = [s for s in scored if s[1] <= 10.0 and abs(s[2]) <= 10.0]
    axis_rows = [s for s in scored if "optical axis" in s[0] and "image" not in s[0]]
    rep.text(
        f"after calibration: {len(within)} of {len(scored)} forces within 10 deg and 10 %; along the optical axis: "
        + "; ".join(f"{n}: {d:.1f} deg, {m:+.1f} %" for n, d, m in axis_rows)
    )
    rep.text(
        "a 2-D model receives only the image-plane part of a force: along the line of sight through the bob it is "
        f"{float(np.linalg.norm(P @ forces[4][1]) / np.linalg.norm(P @ forces[0][1])):.1e} of the calibration force's (nothing to pull back), "
        f"along the optical axis {float(np.linalg.norm(P @ forces[1][1]) / np.linalg.norm(P @ forces[0][1])):.3f}, while the true pendulum turns "
        f"{math.degrees(true_displacement(forces[4][1], ROD_M)[1]):+.2f} and {math.degrees(true_displacement(forces[1][1], ROD_M)[1]):+.2f} deg"
    )
    rep.write()
    return rows


if __name__ == "__main__":
    main()
