"""The 3-D chain as a user runs it: views, Stage 1 on several cameras, chart, Stage 2, evaluation, novel views."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import pytest

import lagsplat.synth.realistic.camera  # noqa: F401  (sets MUJOCO_GL=egl before MuJoCo is imported)

mujoco = pytest.importorskip("mujoco")

ROOT = Path(__file__).resolve().parents[1]


def _run(stage: str, raw: Path, res: Path, *extra: str) -> subprocess.CompletedProcess:
    args = [sys.executable, "-m", "lagsplat", stage, "system=pendulum3d", f"raw_dir={raw}", f"results_dir={res}", "threads=2",
            "stage1.steps=40", "stage1.n_gaussians=96", "stage1.recycle_warmup=10", "stage1.recycle_every=10", "stage1.retries=0",
            "chart.n_metric_samples=4", "chart.gate=false", "stage2.epochs=2", "stage2.windows_per_epoch=40", "evaluate.n_windows=2",
            "evaluate.n_periods=1", *extra]  # fmt: skip
    r = subprocess.run(args, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, f"{stage}: {r.stderr[-2000:]}"
    return r


def test_the_3d_chain_end_to_end(tmp_path):
    from lagsplat.synth.pendulum3d import make_pendulum3d

    raw, res = tmp_path / "raw", tmp_path / "res"
    try:
        make_pendulum3d(raw / "pendulum3d", fps=15.0, duration_s=6.0, size=32, n_views=11, noise_std=1.0)  # the system's 11 views
    except RuntimeError as exc:  # no offscreen GL on this machine
        pytest.skip(str(exc))
    _run("ingest", raw, res)
    assert "computed" in _run("views", raw, res).stdout
    assert "cached, unchanged" in _run("views", raw, res).stdout
    for stage in ("stage1", "chart", "stage2", "evaluate"):
        _run(stage, raw, res)
    m = json.loads((res / "pendulum3d" / "metrics.json").read_text())["metrics"]
    per_cam = m["psnr_per_camera_held_out"]["value"]
    assert len(per_cam) == 12 and all(p > 8.0 for p in per_cam)  # main camera + 11 views, each decoded to something
    assert m["psnr_novel_views_held_out"]["value"] > 8.0 and "novel_view_gap_db_held_out" in m
    assert "eps_freq_truth" in m and m["f_truth_hz"]["value"] == pytest.approx(0.70, abs=0.2)
    # the gap diagnosis reads the 3-D model as it reads a 2-D one (its image localisation through the main camera)
    _run("diagnose", raw, res, "diagnose.refit.epochs=2", "diagnose.where.n_image_frames=4")
    rep = json.loads((res / "pendulum3d" / "diagnosis" / "report.json").read_text())
    assert rep["verdict"] and (res / "pendulum3d" / "diagnosis" / "figures" / "where_image.png").stat().st_size > 1000
    _run("render", raw, res, "render.n_cameras=4", "render.rollout_s=1.0")
    video = res / "pendulum3d" / "figures" / "novel_views.mp4"
    cap = cv2.VideoCapture(str(video))
    n, size = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)), (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
    cap.release()
    assert n == 15 and size == (64, 64)  # 1 s at 15 fps, twice the training resolution
    assert (res / "pendulum3d" / "figures" / "novel_views.png").stat().st_size > 1000

    # the viewer: a click on the most mobile material pushes it; viser serves the splats
    import socket

    import numpy as np
    import torch

    from lagsplat.artifacts import Artifacts
    from lagsplat.viewer.viewer3d import Session3D, serve_viser

    a = Artifacts.at(res / "pendulum3d")
    s = Session3D(a.load_stage1(), a.load_chart(), a.load_stage2()[0])
    q_start = s.q.clone()
    i = int(torch.linalg.matrix_norm(s.ft.J, ord=2).argmax())
    target = s.ft.means(s.q)[0, i].numpy()
    origin = s.ae.decoder.camera.center
    assert s.press_ray(origin, target - origin)
    assert float(s.generalized_force().abs().max()) > 0
    s.step(5)
    pushed = s.q.clone()
    s.reset()
    assert torch.equal(s.q, q_start) and s.generalized_force() is None
    s.step(5)
    assert not torch.allclose(s.q, pushed)
    assert set(s.splats()) == {"centers", "covariances", "rgbs", "opacities"} and s.splats()["centers"].shape[1] == 3
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    urls = []
    serve_viser(s, port, max_seconds=1.0, on_ready=urls.append)
    assert urls == [f"http://127.0.0.1:{port}/"]
    assert np.isfinite(s.q.numpy()).all()
    _browser_orbits_and_pushes(s)


def _browser_orbits_and_pushes(s) -> None:
    """In headless Chromium (WebGL in software): the page opens at the main camera, a click on the most mobile
    material pushes it along the click's line of sight, a mouse drag orbits the camera, a click from the orbited
    view pushes along the new line of sight, and the release button stops the push."""
    import math
    import time
    from contextlib import contextmanager

    import numpy as np
    import torch

    from lagsplat.render.camera import look_at, project_points
    from lagsplat.viewer.browser import CHROMIUM, CHROMIUM_WEBGL_ARGS
    from lagsplat.viewer.viewer3d import client_camera, main_camera_pose, served_viser, wait_for_client

    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.skip("playwright is not installed (pip install playwright)")
    if not Path(CHROMIUM).exists():
        pytest.skip(f"no Chromium at {CHROMIUM} (apt-get update && apt-get install -y chromium)")
    W, H = 900, 700  # viser's panel sits top right; the model is clicked where the main camera sees it
    mobility = torch.linalg.matrix_norm(s.ft.J, ord=2).detach().numpy()

    def click_target(client) -> np.ndarray:
        """Click, as the client's camera shows it, the most mobile opaque primitive that is on the canvas and clear
        of viser's panel; returns its world position (a point on the click's line of sight)."""
        c = client.camera
        cam = look_at(tuple(c.position), tuple(c.look_at), tuple(c.up_direction), W, H, math.degrees(c.fov))
        with torch.no_grad():
            X = s.ft.means(s.q)[0]
            uv, z = (t.numpy() for t in project_points(X, cam))
        clear = (z > 0) & (uv[:, 0] > 20) & (uv[:, 0] < W - 20) & (uv[:, 1] > 20) & (uv[:, 1] < H - 20) & ~((uv[:, 0] > W - 350) & (uv[:, 1] < 230))
        score = np.where(clear, mobility * s.geom.alpha.detach().numpy(), -1.0)
        i = int(score.argmax())
        assert score[i] > 0, "no mobile primitive on the canvas"
        page.mouse.click(float(uv[i, 0]), float(uv[i, 1]))
        return X[i].numpy()

    def wait_until(cond, seconds: float = 10.0) -> bool:
        t0 = time.monotonic()
        while not cond() and time.monotonic() - t0 < seconds:
            time.sleep(0.05)
        return bool(cond())

    def click_and_push(client) -> np.ndarray:
        """Click the model; the push must act along the click's line of sight. Returns that unit ray."""
        X = click_target(client)
        assert wait_until(lambda: s.pushing), "the click on the model did not select it"
        ray = X - np.asarray(client.camera.position)
        ray = ray / np.linalg.norm(ray)
        cos = float(s.push_direction @ ray)
        assert cos > 0.98, f"the push is not along the line of sight (cos {cos:.3f})"
        return ray

    @contextmanager
    def opened(render: str):
        """The viewer served (``render`` mode) and loaded in headless Chromium: yields ``(page, client)``."""
        with served_viser(s, render=render) as (url, server), sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_WEBGL_ARGS, headless=True)
            try:
                pg = browser.new_page(viewport={"width": W, "height": H})
                pg.goto(url)
                pg.wait_for_function("document.querySelector('canvas') !== null", timeout=30_000)
                yield pg, wait_for_client(server)
            finally:
                browser.close()

    with opened("browser") as (page, client):
        page.wait_for_timeout(1500)
        pose = main_camera_pose(s)
        np.testing.assert_allclose(client.camera.position, pose["position"], atol=1e-4)  # opened at the main camera
        s.reset()
        ray = click_and_push(client)
        assert float(s.generalized_force().abs().max()) > 0
        # orbit: drag on the canvas, away from the panel
        p0 = np.asarray(client.camera.position).copy()
        page.mouse.move(0.3 * W, 0.75 * H)
        page.mouse.down()
        page.mouse.move(0.3 * W - 150, 0.75 * H, steps=12)
        page.mouse.up()
        page.wait_for_timeout(1000)
        moved = float(np.linalg.norm(np.asarray(client.camera.position) - p0))
        assert moved > 0.05 * float(np.linalg.norm(p0 - np.asarray(client.camera.look_at))), "the drag did not orbit the camera"
        page.locator("button", has_text="release").click()
        assert wait_until(lambda: not s.pushing), "the release button did not stop the push"
        ray2 = click_and_push(client)  # from the orbited view: along the new line of sight
        assert float(ray @ ray2) < 0.9995  # a different direction

    # the same page drawn by the server: each frame is the decoder's own render of the browser's camera
    with opened("server") as (page, client):
        page.wait_for_timeout(2000)
        cam = client_camera(client.camera, 96)
        assert cam.width == round(96 * W / H)
        c = client.camera  # the camera the page shows: the point it looks at projects to the image centre
        uv, _ = project_points(torch.tensor(np.asarray(c.look_at, float), dtype=torch.float32), cam)
        np.testing.assert_allclose(uv.numpy(), [cam.width / 2, cam.height / 2], atol=0.05)
        s.release()
        with torch.no_grad():  # at rest, so that the page and the reference show one state
            s.q, s.qdot = s.model.q_rest.detach()[None].clone(), torch.zeros_like(s.qdot)
        page.wait_for_timeout(1000)
        shot = cv2.imdecode(np.frombuffer(page.screenshot(), np.uint8), cv2.IMREAD_GRAYSCALE).astype(float)
        ref = cv2.cvtColor(cv2.resize(s.render(cam), (W, H), interpolation=cv2.INTER_LINEAR), cv2.COLOR_RGB2GRAY).astype(float)
        keep = np.ones((H, W), bool)
        keep[:260, W - 380 :] = False  # viser's panel
        keep[:170, :340] = False  # the browser's notice of software WebGL
        corr = float(np.corrcoef(shot[keep], ref[keep])[0, 1])
        assert corr > 0.8, f"the page does not show the server's render (correlation {corr:.2f})"
        ray = click_and_push(client)  # pushing works the same on the server-drawn page
        assert float(np.linalg.norm(ray)) == pytest.approx(1.0)
