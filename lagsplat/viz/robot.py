"""The soft robot's figures (paper §4.4-4.5): a long pressure-driven rollout decoded at high resolution
(Fig. krauss-npz-rollout) and force equilibria at one operating pressure (Fig. krauss-force).

Both read a finished run (clip, Stage 1, chart, Stage 2) and nothing else; any actuated system with a
slender moving body works, the layout of the force panels follows ``segments``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from lagsplat import timeseries  # noqa: E402
from lagsplat.artifacts import Artifacts  # noqa: E402
from lagsplat.dynamics.integrators import actuation_schedule, initial_state, rollout  # noqa: E402
from lagsplat.forces.transport import ForceTransport  # noqa: E402
from lagsplat.io.atomic import atomic_write, write_json  # noqa: E402
from lagsplat.io.clip import HELD_OUT, TRAIN  # noqa: E402
from lagsplat.viz.rollout import visibility_basis  # noqa: E402

__all__ = ["RobotBody", "foreground", "robot_body", "force_panels", "panel_equilibria", "robot_rollout_figure", "robot_force_figure"]


def _principal_direction(points: np.ndarray) -> np.ndarray:
    """Unit direction ``[2]`` of largest spread of ``points [P,2]`` (sign arbitrary)."""
    x = points - points.mean(0)
    return np.linalg.eigh(x.T @ x)[1][:, -1]


@dataclass(frozen=True)
class RobotBody:
    """The moving body at one state, read off the decoder's motion field (chart pixels).

    Attributes:
        pixels: ``[P,2]`` centres of the body's pixels (:func:`robot_body`).
        base, axis: ``[2]`` the clamped end (the end that moves least) and the unit direction from it to the free end.
        length: px, from the base to the free end along ``axis`` (2nd to 98th percentile of the projections).
        s: ``[P]`` each body pixel's position along the body, 0 at the base and 1 at the free end.
    """

    pixels: np.ndarray
    base: np.ndarray
    axis: np.ndarray
    length: float
    s: np.ndarray

    def point(self, s: float) -> np.ndarray:
        """The point ``[2]`` (px) at ``s`` along the body: the mean of the body pixels nearest to ``s``."""
        near = np.abs(self.s - s) <= max(0.06, float(np.sort(np.abs(self.s - s))[min(2, len(self.s) - 1)]))
        return self.pixels[near].mean(0)

    def direction(self, s: float, half_width: float) -> np.ndarray:
        """Unit local axis ``[2]`` at ``s``: principal direction of the body pixels within ``half_width`` of it."""
        near = np.abs(self.s - s) <= half_width
        if near.sum() < 3:
            return self.axis
        e = _principal_direction(self.pixels[near])
        return e if e @ self.axis >= 0 else -e


def foreground(img: np.ndarray, threshold: float = 0.15) -> np.ndarray:
    """Largest channel difference ``[H,W]`` of an image ``[H,W,3]`` in [0, 1] from its background colour
    (the median of its border pixels); the foreground is where it is at least ``threshold``."""
    border = np.concatenate([img[0], img[-1], img[:, 0], img[:, -1]])
    return np.abs(img - np.median(border, 0)).max(-1)


def robot_body(ft: ForceTransport, q: torch.Tensor, image: np.ndarray, sigma: float = 1.0, threshold: float = 0.15) -> RobotBody:
    """The moving body of the decoder at state ``q [1,d]`` (:class:`RobotBody`).

    Body pixels are foreground pixels of the decoded ``image [H,W,3]`` (:func:`foreground` at ``threshold``)
    where a brush of radius ``sigma`` px moves the state (``|J_bar(x)|`` at least a tenth of its largest value):
    a static clamp is not part of the body, nor is the background the decoder repaints while the body moves.

    Raises:
        ValueError: if fewer than 3 pixels qualify (no body to push).
    """
    H, W = image.shape[:2]
    yy, xx = np.mgrid[0:H, 0:W]
    grid = np.stack([xx.ravel() + 0.5, yy.ravel() + 0.5], 1)
    Jb = ft.brush_jacobian(q, torch.as_tensor(grid, dtype=torch.float32), sigma).double().numpy()
    mag = np.linalg.norm(Jb.reshape(len(grid), -1), axis=1)
    body = (mag >= 0.1 * mag.max()) & (foreground(image).ravel() >= threshold)
    if body.sum() < 3:
        raise ValueError(f"only {int(body.sum())} foreground pixels move: no body to apply forces to")
    px, m = grid[body], mag[body]
    c = px.mean(0)
    axis = _principal_direction(px)
    proj = (px - c) @ axis
    lo, hi = np.percentile(proj, [2, 98])
    if m[proj <= np.percentile(proj, 25)].mean() > m[proj >= np.percentile(proj, 75)].mean():  # the clamped end moves least
        axis, proj, (lo, hi) = -axis, -proj, (-hi, -lo)
    return RobotBody(pixels=px, base=c + lo * axis, axis=axis, length=float(hi - lo), s=(proj - lo) / max(hi - lo, 1e-9))


def force_panels(segments: int) -> list[tuple[str, list[tuple[float, str, float]]]]:
    """The force panels of paper Fig. krauss-force: ``(caption, [(s, "lateral" | "axial", sign), ...])``.

    ``s`` is the application point along the body (0 base, 1 free end); a lateral force points across the
    local axis ``e``, along ``sign (e_y, -e_x)`` (image coordinates, y down: to the image's right for a body
    hanging down when ``sign`` is +1), an axial one away from the base times ``sign``. With two or
    more segments: both segments bent left / right, the first segment alone, the second segment stretched /
    shortened at its end, the first likewise, and two opposed forces at the junction and the free end;
    with one segment the single-segment subset.
    """
    n = max(1, int(segments))
    if n == 1:
        return [
            ("bend left (middle)", [(0.5, "lateral", -1.0)]), ("bend right (middle)", [(0.5, "lateral", 1.0)]),
            ("bend left (tip)", [(1.0, "lateral", -1.0)]), ("bend right (tip)", [(1.0, "lateral", 1.0)]),
            ("stretch (tip, outwards)", [(1.0, "axial", 1.0)]), ("shorten (tip, inwards)", [(1.0, "axial", -1.0)]),
            ("opposed: middle and tip", [(0.5, "lateral", 1.0), (1.0, "lateral", -1.0)]),
        ]  # fmt: skip
    j, m1, m2, end2 = 1.0 / n, 0.5 / n, 1.5 / n, 2.0 / n
    return [
        ("both segments, left", [(m1, "lateral", -1.0), (m2, "lateral", -1.0)]),
        ("both segments, right", [(m1, "lateral", 1.0), (m2, "lateral", 1.0)]),
        ("first segment, left", [(m1, "lateral", -1.0)]), ("first segment, right", [(m1, "lateral", 1.0)]),
        ("second segment, outwards", [(end2, "axial", 1.0)]), ("second segment, inwards", [(end2, "axial", -1.0)]),
        ("first segment, outwards", [(j, "axial", 1.0)]), ("first segment, inwards", [(j, "axial", -1.0)]),
        ("opposed: junction and tip", [(j, "lateral", 1.0), (end2, "lateral", -1.0)]),
    ]  # fmt: skip


def panel_equilibria(model, ft: ForceTransport, body: RobotBody, panels, q_op: torch.Tensor, u: torch.Tensor | None, force: float, sigma: float, half_width: float):
    """Loaded equilibria of ``model`` under each panel's forces (:func:`force_panels`), all of magnitude ``force``.

    Each force is applied with the visible brush of radius ``sigma`` px at ``body.point(s)`` at the operating
    state ``q_op [1,d]`` and pulled back through the decoder Jacobian, ``J^T f`` (paper Eq. 9); the equilibria
    solve ``dV/dq = J^T f + b(q)^T u`` from ``q_op`` (:meth:`~lagsplat.models.lagrangian.Lagrangian.loaded_equilibrium`).

    Returns:
        ``(q_eq [P,d], arrows, moved)``: per panel the list of ``(selection, unit direction [2])`` of its forces and
        the largest displacement (px) of one of its application points.

    Raises:
        RuntimeError: if an equilibrium does not converge.
    """
    f_gen, arrows = [], []
    for _, forces in panels:
        g, arr = torch.zeros(1, ft.d), []
        for s, kind, sign in forces:
            e = body.direction(min(s, 1.0 - 1e-6), half_width)
            dirn = sign * (e if kind == "axial" else np.array([e[1], -e[0]]))
            sel = ft.select(q_op, torch.as_tensor(body.point(s)[None], dtype=torch.float32), sigma)
            g = g + ft.pullback(sel, torch.as_tensor(force * dirn[None], dtype=torch.float32))
            arr.append((sel, dirn))
        f_gen.append(g)
        arrows.append(arr)
    f = torch.cat(f_gen)
    q_eq = model.loaded_equilibrium(f, u=None if u is None else u.expand(len(f), -1), q0=q_op.expand(len(f), -1)).float()
    moved = [
        max(float(np.linalg.norm((ft.application_point(q_eq[i : i + 1], sel) - ft.application_point(q_op, sel)).numpy())) for sel, _ in arrows[i])
        for i in range(len(panels))
    ]
    return q_eq, arrows, moved


def _load(a: Artifacts):
    a.require("clip", "stage1", "chart", "stage2")
    clip, chart, ae = a.load_clip(), a.load_chart(), a.load_stage1()
    model, _ = a.load_stage2()
    return clip, chart, ae.eval(), model.eval()


def _render(ae, chart, q: np.ndarray, size: int | None = None) -> np.ndarray:
    """Decode chart states ``q [B,d]`` at ``size x size`` (default: the recording's size): images ``[B,H,W,3]`` in [0, 1]."""
    H, W = (chart.height, chart.width) if size is None else (size, size)
    with torch.no_grad():
        z = chart.to_raw(torch.as_tensor(np.asarray(q), dtype=torch.float32))
        return ae.decoder(z, H, W).permute(0, 2, 3, 1).numpy()


def _save(fig, out: Path) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(out) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def robot_rollout_figure(a: Artifacts, out: Path, seconds: float = 30.0, size: int = 256, sigma: float = 1.0, title: str = "", provenance: str = "") -> dict[str, Any]:
    """A free rollout under the recorded pressures over the held-out split (paper Fig. krauss-npz-rollout).

    From the encoded state (smoothed over ``sigma`` frames) at the first held-out frame, the model is driven by
    the measured actuation only, never re-anchored, for ``seconds`` (or the held-out segment, if shorter).
    Top: each latent coordinate in the eigenbasis of ``G_bar`` (its share of the visibility in the label),
    encoded against predicted, and the actuation. Bottom: at the last step, the recorded frame, the decoder at
    the encoded state and at the predicted state, both rendered at ``size x size``.

    Returns:
        ``{"seconds", "frames", "offset_px", "offset_px_at_size", "figure"}``: ``offset_px`` is the distance
        between the primitives at the predicted and at the encoded last state, averaged with the weights of
        their rendered opacities at the encoded state (recording pixels), the figure's caption number.

    Raises:
        FileNotFoundError: naming a missing artifact. ValueError: if the held-out split has fewer than 4 frames.
    """
    clip, chart, ae, model = _load(a)
    dt = float(np.median(np.diff(chart.t)))
    ho = max(chart.segments(HELD_OUT), key=len)
    edge = timeseries.smoothing_edge(sigma)
    first = int(np.flatnonzero(chart.episode == chart.episode[ho[0]])[0])
    s0 = max(int(ho[0]), first + edge)
    n = min(int(round(seconds / dt)) + 1, int(ho[-1]) + 1 - s0)
    if n < 4:
        raise ValueError(f"{a.chart}: the held-out split leaves {n} frames for the rollout figure (need >= 4)")
    lead = max(s0 - edge, first)
    q_s = timeseries.gaussian_smooth(chart.q[lead : s0 + n], sigma)[s0 - lead :]
    q0, v0 = initial_state(q_s, np.array([0]), dt)
    u = chart.u[s0 : s0 + n]
    pred = rollout(model, q0, v0, dt, n, u=actuation_schedule(u[None], dt))[0][0].numpy()

    ft = ForceTransport.from_autoencoder(ae, chart)
    with torch.no_grad():
        qe = torch.as_tensor(q_s[-1:], dtype=torch.float32)
        mp, me = ft.means(torch.as_tensor(pred[-1:], dtype=torch.float32))[0].numpy(), ft.means(qe)[0].numpy()
        w = ft.opacity(qe)[0].numpy() * (np.linalg.norm(ft.J.numpy().reshape(len(me), -1), axis=1) > 0)
    offset = float((np.linalg.norm(mp - me, axis=1) * w).sum() / max(w.sum(), 1e-12))
    share, V = visibility_basis(chart.G_bar)
    t = chart.t[s0 : s0 + n] - chart.t[s0]
    renders = _render(ae, chart, np.stack([q_s[-1], pred[-1]]), size)

    d = chart.d
    fig = plt.figure(figsize=(9, 1.5 * d + 1.5 + 3.4))
    gs = fig.add_gridspec(d + 2, 3, height_ratios=[1.5] * d + [1.2, 3.4])
    for k in range(d):
        ax = fig.add_subplot(gs[k, :])
        ax.plot(t, q_s @ V[:, k], ".", ms=1.5, color="k", label="encoded (held-out video)")
        ax.plot(t, pred @ V[:, k], "-", lw=1.0, color="tab:red", label="predicted (pressure-driven, free)")
        ax.set_ylabel(f"q{k + 1} ({100 * share[k]:.0f} %)", fontsize=8)
        ax.tick_params(labelbottom=False)
        if k == 0:
            ax.legend(loc="upper right", fontsize=7, ncol=2)
            ax.set_title((title + "\n" if title else "") + f"{t[-1]:.1f} s of free rollout on the held-out split; "
                         f"offset at the last step {offset:.2f} px ({offset * size / chart.width:.1f} px at {size}x{size})", fontsize=9)  # fmt: skip
    ax = fig.add_subplot(gs[d, :])
    if u.shape[1]:
        ax.plot(t, u, lw=0.8)
        ax.legend([f"u{j + 1}" for j in range(u.shape[1])], fontsize=6, ncol=u.shape[1], loc="upper right")
    ax.set_ylabel("actuation", fontsize=8)
    ax.set_xlabel("time since the first held-out frame (s)")
    real = clip.images[s0 + n - 1]
    for c, (img, lab) in enumerate([(real, f"recording ({chart.width}x{chart.height})"), (renders[0], f"decoded at encoded q ({size}x{size})"), (renders[1], f"decoded at predicted q ({size}x{size})")]):
        ax = fig.add_subplot(gs[d + 1, c])
        ax.imshow(np.clip(img if img.dtype != np.uint8 else img / 255.0, 0, 1), interpolation="nearest" if c == 0 else "antialiased")
        ax.set_title(lab, fontsize=8)
        ax.set_xticks([])
        ax.set_yticks([])
    if provenance:
        fig.text(0.01, 0.005, f"data: {provenance}", fontsize=6, color="0.4")
    fig.tight_layout(rect=(0, 0.015, 1, 1))
    _save(fig, out)
    return {"seconds": float(t[-1]), "frames": int(n), "offset_px": offset, "offset_px_at_size": offset * size / chart.width, "figure": str(out)}


def robot_force_figure(
    a: Artifacts, out: Path, record_path: Path, segments: int = 2, size: int = 256, sigma: float = 1.5, displacement: float = 0.15, title: str = ""
) -> dict[str, Any]:
    """Loaded equilibria at one operating pressure under the panels of :func:`force_panels` (paper Fig. krauss-force).

    The operating pressure is the median of the training frames' actuation; its equilibrium (no force) is the
    rest envelope, drawn in every panel as a white dashed contour of the decoded unloaded image's foreground (:func:`foreground`). Each force is
    applied with the visible brush (radius ``sigma`` px) at a point along the body and pulled back through the
    decoder Jacobian (paper Eq. 9); every force has one magnitude, aimed (two rescalings from the response to a
    unit force) at a largest application-point displacement of ``displacement`` times the body's length (a model that
    stiffens under load stays below it: ``displacement_px`` in the record is what it did), and the arrows share one scale.

    Returns:
        ``{"pressure", "force", "length_px", "panels": [{"caption", "q_eq", "displacement_px"}], "figure"}``,
        also written to ``record_path`` (JSON).

    Raises:
        FileNotFoundError: naming a missing artifact. ValueError: if the decoder shows no moving body.
        RuntimeError: if a loaded equilibrium does not converge.
    """
    _, chart, ae, model = _load(a)
    train = chart.split == TRAIN
    u_op = np.median(chart.u[train], 0) if chart.n_u else np.zeros(0)
    U = torch.as_tensor(u_op[None], dtype=torch.float32) if chart.n_u else None
    q_op = model.loaded_equilibrium(u=U).float() if U is not None else model.loaded_equilibrium().float()
    ft = ForceTransport.from_autoencoder(ae, chart)
    body = robot_body(ft, q_op, _render(ae, chart, q_op.numpy())[0], sigma)
    panels = force_panels(segments)
    half = 0.5 / max(1, segments)

    _, _, moved = panel_equilibria(model, ft, body, panels, q_op, U, 1.0, sigma, half)
    F = displacement * body.length / max(max(moved), 1e-9)
    q_eq, arrows, moved = panel_equilibria(model, ft, body, panels, q_op, U, F, sigma, half)
    F *= displacement * body.length / max(max(moved), 1e-9)  # the response may be nonlinear: one more rescale
    q_eq, arrows, moved = panel_equilibria(model, ft, body, panels, q_op, U, F, sigma, half)

    imgs = _render(ae, chart, q_eq.numpy(), size)
    rest = foreground(_render(ae, chart, q_op.numpy(), size)[0])
    k = size / chart.width
    cols = 3
    rows = int(np.ceil(len(panels) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.0 * cols, 3.3 * rows + 0.6))
    letters = "abcdefghijklmnop"
    for i, ax in enumerate(np.ravel(axes)):
        ax.set_xticks([])
        ax.set_yticks([])
        if i >= len(panels):
            ax.axis("off")
            continue
        ax.imshow(np.clip(imgs[i], 0, 1))
        ax.contour(rest, levels=[0.15], colors="white", linestyles="--", linewidths=1.0)
        for sel, dirn in arrows[i]:
            p = ft.application_point(q_eq[i : i + 1], sel)[0].numpy() * k
            L = 0.3 * body.length * k
            ax.annotate("", xy=p, xytext=p - L * dirn, arrowprops={"arrowstyle": "-|>", "color": "tab:red", "lw": 2.0})
        ax.set_title(f"({letters[i]}) {panels[i][0]}", fontsize=8)
    pr = ", ".join(f"{x:.3g}" for x in u_op) if len(u_op) else "none"
    fig.suptitle((title + "\n" if title else "") + f"loaded equilibria at the operating pressure ({pr}); one force magnitude, arrows to scale", fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 0.96))
    _save(fig, out)
    record = {
        "pressure": [float(x) for x in u_op], "force": float(F), "length_px": body.length, "figure": str(out),
        "panels": [{"caption": c, "q_eq": q_eq[i].tolist(), "displacement_px": moved[i]} for i, (c, _) in enumerate(panels)],
    }  # fmt: skip
    write_json(record_path, record)
    return record
