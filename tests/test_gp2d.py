"""GP-2D (lagsplat.baselines.gp2d_*): the field fits frames drawn by OpenCV, the forecaster learns an exact oscillation,
and the importer of the original GaussianPrediction's frames rejects every bad input with one line naming the file."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from lagsplat.baselines.gp2d import fit_gp2d
from lagsplat.baselines.gp2d_field import GP2DConfig, GP2DField, fit_field, fourier
from lagsplat.baselines.gp2d_forecast import KeypointForecaster, forecast, train_forecaster
from lagsplat.baselines.gp_frames import load_prediction_frames, prediction_arrays
from lagsplat.io.clip import ClipError

DT = 1 / 30
pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _disc_clip(n: int = 48, size: int = 32, f_hz: float = 0.8) -> np.ndarray:
    """A red disc swinging on an arc over a fixed noise texture, drawn by OpenCV (anti-aliased): uint8 ``[n,size,size,3]``."""
    rng = np.random.default_rng(0)
    bg = (rng.random((size, size, 3)) * 90 + 80).astype(np.uint8)
    out = []
    for i in range(n):
        th = 0.6 * math.cos(2 * math.pi * f_hz * i * DT)
        img = bg.copy()
        c = (int(round(16 * (size / 2 + 0.7 * size / 2 * math.sin(th)))), int(round(16 * (0.15 * size + 0.6 * size * math.cos(th)))))
        cv2.circle(img, c, int(16 * size * 0.12), (40, 40, 220), -1, lineType=cv2.LINE_AA, shift=4)
        out.append(img[..., ::-1].copy())
    return np.stack(out)


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2) / 255.0**2
    return float(-10 * math.log10(mse))


def test_sizes_follow_the_resolution_rule_and_the_encoding_is_sinusoidal() -> None:
    small, large = GP2DConfig().resolved(32, 32), GP2DConfig().resolved(128, 128)
    assert (small.n_gaussians, small.n_keypoints, small.k_neighbours, small.iterations) == (256, 16, 4, 6000)
    assert GP2DConfig().resolved(48, 128).iterations == 12000  # 6144 pixels: nearest to 64^2
    assert (large.n_gaussians, large.n_keypoints, large.k_neighbours, large.iterations) == (4096, 48, 6, 20000)
    assert GP2DConfig(n_gaussians=100, iterations=7).resolved(128, 128).n_gaussians == 100
    g = fourier(torch.tensor([[0.5]]), 3)
    assert torch.allclose(g, torch.tensor([[math.sin(0.5), math.sin(1.0), math.sin(2.0), math.cos(0.5), math.cos(1.0), math.cos(2.0)]]))


def test_the_canonical_field_renders_its_first_frame_colours_and_has_finite_gradients() -> None:
    frames = _disc_clip(4)
    x = torch.from_numpy(frames).permute(0, 3, 1, 2).float() / 255
    field = GP2DField(x[0], x[0], GP2DConfig().resolved(32, 32), torch.Generator().manual_seed(0))
    img = field.render(field.mu[None], field.theta[None])
    assert img.shape == (1, 3, 32, 32)
    assert float((img[0].detach() - x[0]).abs().mean()) < 0.05  # grid colours over the same background: close to the frame
    img.sum().backward()
    assert all(torch.isfinite(p.grad).all() for p in (field.mu, field.log_scale, field.color_raw, field.opacity_raw, field.bg_raw))


def test_the_field_reproduces_a_clip_drawn_by_another_renderer_and_its_key_points_follow_the_disc() -> None:
    frames = _disc_clip(48)
    field, hist = fit_field(frames, GP2DConfig(iterations=900), seed=0)
    with torch.no_grad():
        S = field.keypoint_states(torch.linspace(0, 1, len(frames)))
        rec = (field.render(*field.blend(S)).clamp(0, 1).permute(0, 2, 3, 1).numpy() * 255 + 0.5).astype(np.uint8)
    static = _psnr(np.broadcast_to(np.median(frames, 0), frames.shape), frames)  # the still background alone
    assert _psnr(rec, frames) > static + 3.0, (_psnr(rec, frames), static)
    travel = (S[:, :, :2].amax(0) - S[:, :, :2].amin(0)).norm(dim=-1)
    j = int(travel.argmax())
    disc_x = np.sin(0.6 * np.cos(2 * math.pi * 0.8 * np.arange(len(frames)) * DT))
    assert float(travel[j]) > 0.3 and abs(np.corrcoef(S[:, j, 0].numpy(), disc_x)[0, 1]) > 0.9  # it swings with the disc
    assert hist["loss"][-1][1] < hist["loss"][0][1]


def _circle_states(n: int, K: int = 3) -> np.ndarray:
    """Key points turning on circles of radius 0.3 at 0.8 Hz, rotations turning with them: ``[n,K,4]``."""
    t = np.arange(n) * DT
    ph = 2 * math.pi * 0.8 * t
    S = np.zeros((n, K, 4), np.float32)
    for j in range(K):
        S[:, j, 0], S[:, j, 1] = 0.3 * np.cos(ph + j), 0.3 * np.sin(ph + j) - 0.2 * j
        S[:, j, 2], S[:, j, 3] = np.cos(0.5 * np.sin(ph)), np.sin(0.5 * np.sin(ph))
    return S


def test_the_forecaster_alone_learns_one_step_of_an_exact_orbit_and_rolls_out_unit_rotations() -> None:
    S = _circle_states(160)
    cfg = GP2DConfig(gcn_epochs=150, gcn_hidden=32, gcn_stages=2)
    model, hist = train_forecaster(S[:120], cfg, seed=0)
    with torch.no_grad():
        X = torch.stack([torch.as_tensor(S[i : i + 10]) for i in range(110, 150)])
        err = (model(X)[..., :2] - torch.as_tensor(S[120:160, :, :2])).norm(dim=-1)
    assert float(err.mean()) < 0.1 * 0.3, float(err.mean())  # far below the amplitude, also on unseen windows
    roll = forecast(model, S[110:120], 30)
    assert roll.shape == (30, 3, 4) and np.allclose(np.linalg.norm(roll[..., 2:], axis=-1), 1.0, atol=1e-5)
    assert hist["loss"][-1][1] < hist["loss"][0][1]
    assert isinstance(model, KeypointForecaster)


def test_fit_gp2d_needs_a_history_of_frames() -> None:
    with pytest.raises(ValueError, match="at least 11 training frames"):
        fit_gp2d(_disc_clip(8), GP2DConfig(iterations=2))


# ----------------------------------------------------------------------------- importer of the original's frames
def _write_predictions(folder: Path, n: int = 20, t0: float = 4.0, size: tuple[int, int] = (24, 32)) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    files = []
    rows = ["file,time_s"]
    for i in range(n):
        p = folder / f"{i:05d}.png"
        img = np.full((*size, 3), 10 * (i % 20), np.uint8)
        cv2.imwrite(str(p), img)
        files.append(p)
        rows.append(f"{p.name},{t0 + i * DT:.6f}")
    (folder / "times.csv").write_text("\n".join(rows) + "\n")
    return files


def _load(folder: Path):
    return load_prediction_frames(folder, 4.0, DT, 24, 32)


def test_the_importer_reads_a_good_folder(tmp_path: Path) -> None:
    _write_predictions(tmp_path / "p", n=40)
    frames, t = _load(tmp_path / "p")
    assert frames.shape == (40, 24, 32, 3) and t[0] == pytest.approx(4.0) and frames[3, 0, 0, 0] == 30
    ho, ends, n = prediction_arrays(frames, 20, 5)
    assert ho.shape[0] == 20 and ends.shape[0] == 10 and n == 40
    assert prediction_arrays(frames, 36, 5)[1] is None  # no two periods past the held-out frames: no amplitude row


def _edit_times(folder: Path, fn) -> None:
    lines = (folder / "times.csv").read_text().splitlines()
    (folder / "times.csv").write_text("\n".join(fn(lines)) + "\n")


@pytest.mark.parametrize(
    "defect, message",
    [
        ("no_folder", r"not a folder of predicted frames"),
        ("no_times", r"times\.csv: missing"),
        ("bad_header", r"times\.csv: the first line must be the header"),
        ("bad_row", r"times\.csv line 4: expected 'file,time_s'"),
        ("too_few", r"times\.csv: 5 predicted frames listed, at least 16"),
        ("missing_image", r"00007\.png: listed in times\.csv but missing"),
        ("unreadable", r"00003\.png: cannot decode image"),
        ("other_size", r"00002\.png: 16x16 pixels, the clip's frames are 32x24"),
        ("gap", r"00011\.png: at .* s after .* s; predicted frames must be 0\.03333 s apart"),
        ("misnumbered", r"00005\.png: at .* predicted frames must be"),
        ("late_start", r"00000\.png: the first predicted frame is at 5 s, the held-out segment starts at 4 s"),
    ],
)
def test_the_importer_rejects_each_bad_input_naming_the_file(tmp_path: Path, defect: str, message: str) -> None:
    folder = tmp_path / "pred"
    files = _write_predictions(folder) if defect != "no_folder" else []
    if defect == "no_times":
        (folder / "times.csv").unlink()
    elif defect == "bad_header":
        _edit_times(folder, lambda ls: ["name,t", *ls[1:]])
    elif defect == "bad_row":
        _edit_times(folder, lambda ls: [*ls[:3], "00002.png;0.1", *ls[4:]])
    elif defect == "too_few":
        _edit_times(folder, lambda ls: ls[:6])
    elif defect == "missing_image":
        files[7].unlink()
    elif defect == "unreadable":
        files[3].write_bytes(b"not a png")
    elif defect == "other_size":
        cv2.imwrite(str(files[2]), np.zeros((16, 16, 3), np.uint8))
    elif defect == "gap":
        _edit_times(folder, lambda ls: ls[:11] + ls[12:])  # frame 10 missing
    elif defect == "misnumbered":
        _edit_times(folder, lambda ls: [*ls[:5], ls[6], ls[5], *ls[7:]])  # two rows swapped
    elif defect == "late_start":
        _edit_times(folder, lambda ls: [ls[0]] + [f"{r.split(',')[0]},{float(r.split(',')[1]) + 1.0:.6f}" for r in ls[1:]])
    with pytest.raises(ClipError, match=message):
        _load(folder)


def test_key_point_blending_matches_its_definition_and_its_gradients_repeat_bit_for_bit() -> None:
    """``Delta mu_i = sum_j w_ij (P_j - p_j)`` over the k nearest key points; backward passes agree exactly with threads."""
    rng = np.random.default_rng(3)
    frames = rng.integers(0, 255, (2, 64, 64, 3), dtype=np.uint8)
    x = torch.from_numpy(frames).permute(0, 3, 1, 2).float() / 255.0
    field = GP2DField(x[0], x[1], GP2DConfig().resolved(64, 64), torch.Generator().manual_seed(0))
    field.init_keypoints(0)
    t = torch.tensor([0.1, 0.4, 0.7, 0.9])
    S = field.keypoint_states(t)
    mu_t, theta_t = field.blend(S)
    k = field.cfg.k_neighbours
    idx = torch.cdist(torch.cat([field.mu, 0.5 * field.feature], -1), torch.cat([field.kp_pos, 0.5 * field.kp_feat], -1))
    idx = idx.topk(k, largest=False).indices
    logits = field.weight_net(fourier(field.mu, field.L_WEIGHT))
    wx, wr = torch.softmax(logits[:, :k], -1), torch.softmax(logits[:, k:], -1)
    ref_mu = field.mu[None] + (wx[None, :, :, None] * (S[:, idx, :2] - field.kp_pos[idx][None])).sum(2)
    rot = (wr[None, :, :, None] * S[:, idx, 2:4]).sum(2)
    torch.testing.assert_close(mu_t, ref_mu, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(theta_t, field.theta[None] + torch.atan2(rot[..., 1], rot[..., 0]), rtol=1e-5, atol=1e-6)

    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        grads = []
        for _ in range(3):
            field.zero_grad()
            mu_t, theta_t = field.blend(field.keypoint_states(t))
            (mu_t.square().sum() + theta_t.square().sum()).backward()
            grads.append([p.grad.clone() for p in field.parameters() if p.grad is not None])
    finally:
        torch.set_num_threads(before)
    for g in grads[1:]:
        assert all(torch.equal(a, b) for a, b in zip(grads[0], g))
