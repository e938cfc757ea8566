"""Interactive viewer: the drag session without a browser, then the page in headless Chromium.

Session tests run on two systems: the trained toy (``results/toy``, skipped
when its artifacts are missing) and a hand-built pendulum
(:func:`lagsplat.viewer.synthetic.synthetic_pendulum`, always available). The
browser test drives the real page with Playwright and Chromium at
``/usr/bin/chromium`` (``apt-get install -y chromium``); it is skipped, with
the reason, when either is missing.
"""

from __future__ import annotations

import json
import urllib.request
from pathlib import Path

import numpy as np
import pytest
import torch

from lagsplat.io.clip import TRAIN
from lagsplat.viewer.browser import CHROMIUM, served_page
from lagsplat.viewer.session import Session, load_session
from lagsplat.viewer.synthetic import synthetic_pendulum

pytestmark = pytest.mark.usefixtures("one_torch_thread")

ROOT = Path(__file__).resolve().parents[1]
TOY = ROOT / "results" / "toy"
TOY_FILES = ("stage1.pt", "chart.npz", "stage2.pt")
DRAG_PX = 8.0  # pointer travel of every drag, training pixels


def _have_toy() -> bool:
    return all((TOY / f).exists() for f in TOY_FILES)


def _session(which: str, **kw) -> Session:
    kw.setdefault("initial", "rest")
    if which == "toy":
        if not _have_toy():
            pytest.skip(f"the trained toy system is missing ({TOY}: run `snakemake -c2 toy`)")
        return load_session(TOY, **kw)
    return Session(*synthetic_pendulum(), **kw)


@pytest.fixture(scope="module", params=["toy", "synthetic"])
def system(request) -> str:
    return request.param


def _drag(s: Session, x: float, y: float, steps: int) -> float:
    """Press at (x, y), move DRAG_PX to the right in 4 moves, hold for ``steps``; return |q - q_rest|."""
    assert s.press(x, y)
    for k in range(1, 5):
        s.move(x + DRAG_PX * k / 4, y)
        s.step(3)
    s.step(steps)
    return s.state()["dist_rest"]


def _background_point(s: Session) -> tuple[float, float]:
    """The pixel centre where a grab moves the image least (static background)."""
    m = s.mobility_map()
    r, c = np.unravel_index(int(np.argmin(m)), m.shape)
    return float(c) + 0.5, float(r) + 0.5


# ---------------------------------------------------------------- session, no browser
def test_drag_on_the_object_moves_it_and_release_returns_to_rest(system):
    s = _session(system)
    s.set_params(damping=4.0, inertia=0.25)  # settle within a few simulated seconds
    x, y = s.most_mobile_point()
    p0 = s.state()
    assert p0["dist_rest"] < 1e-6 and p0["grab"] is None
    on = _drag(s, x, y, 90)
    st = s.state()
    assert on > 0.02 and st["grab"] is not None
    assert st["grab"]["pointer"] == pytest.approx([x + DRAG_PX, y])
    # the held material (the selection made at rest) followed the pointer a good part of the way, not past it
    sel = s.transport.select(s.q_rest, torch.tensor([[x, y]]), s.sigma)
    moved = (s.transport.application_point(torch.tensor([st["q"]]), sel) - s.transport.application_point(s.q_rest, sel))[0]
    assert 0.25 * DRAG_PX < float(moved[0]) < 1.1 * DRAG_PX, moved
    assert st["grab"]["point"][0] - float(s.transport.application_point(s.q_rest, sel)[0, 0]) == pytest.approx(float(moved[0]), abs=1e-3)
    s.release()
    assert s.state()["grab"] is None
    s.step(120)
    assert s.state()["dist_rest"] < 0.03 * on
    assert s.state()["diverged"] == 0


def test_the_grab_reports_how_far_the_held_material_moved_in_training(system):
    s = _session(system)
    x, y = s.most_mobile_point()
    assert s.press(x, y)
    on = s.state()["grab"]["seen_px"]
    train = np.asarray(s.chart.split) == TRAIN
    sel = s.transport.select(s.q_rest, torch.tensor([[x, y]]), s.sigma)
    want = float(s.transport.observed_motion(sel, torch.as_tensor(np.asarray(s.chart.q, np.float32)[train]))[0])
    assert on == pytest.approx(want, rel=1e-5) and on > 1.0
    s.release()
    if s.press(*_background_point(s)):  # the brush may reach nothing there
        assert s.state()["grab"]["seen_px"] < on / 50


def test_a_drag_on_the_static_background_moves_less_than_a_fiftieth(system):
    s = _session(system)
    s.set_params(damping=4.0, inertia=0.25)
    on = _drag(s, *s.most_mobile_point(), 60)
    s.reset()
    off = _drag(s, *_background_point(s), 60)
    assert off < on / 50, (off, on)


def test_stiffness_slider_gives_a_smaller_static_deflection(system):
    defl = {}
    for k in (1.0, 4.0):
        s = _session(system)
        s.set_params(damping=4.0, inertia=0.25, stiffness=k)
        defl[k] = _drag(s, *s.most_mobile_point(), 150)
        s.step(15)
        assert s.state()["dist_rest"] == pytest.approx(defl[k], rel=0.05)  # settled: a static deflection
    # spring in series with the model: x = s J^2 d / (k + s J^2), with s J^2 = k at the auto scale -> 1/2 vs 1/5
    assert defl[4.0] < 0.6 * defl[1.0], defl


def test_damping_slider_speeds_up_the_decay():
    res = {}
    for b in (0.25, 4.0):
        s = _session("synthetic")
        s.set_params(damping=b)
        _drag(s, *s.most_mobile_point(), 30)
        s.release()
        start = s.state()["dist_rest"]
        s.step(40)
        amp = []
        for _ in range(40):  # the amplitude over more than one period (0.8 Hz at 30 steps/s)
            s.step()
            amp.append(s.state()["dist_rest"])
        res[b] = max(amp) / start
    assert res[4.0] < 0.5 * res[0.25], res


def test_compiled_and_torch_dynamics_agree(system):
    traj = {}
    for fast in (False, True):
        s = _session(system, initial="held_out", fast=fast)
        assert s.state()["compiled"] is fast
        s.set_params(stiffness=2.0, inertia=0.5, damping=0.5)
        x, y = s.most_mobile_point()
        s.step(5)
        s.press(x, y)
        s.move(x + DRAG_PX, y)
        s.step(20)
        s.release()
        s.step(10)
        traj[fast] = np.array(s.state()["q"])
    np.testing.assert_allclose(traj[True], traj[False], atol=1e-4)


def test_press_on_nothing_holds_nothing_and_params_are_checked():
    s = _session("synthetic")
    assert not s.press(1e4, 1e4)
    s.move(0.0, 0.0)
    s.step(5)
    assert s.state()["grab"] is None and s.state()["dist_rest"] < 1e-6
    assert s.set_params(inertia=100.0, damping=1e-3)["inertia"] == 4.0  # clamped to 0.25x .. 4x
    assert s.params["damping"] == 0.25
    with pytest.raises(ValueError, match="stiffness"):
        s.set_params(stiffness=-1.0)
    with pytest.raises(ValueError, match="finite"):
        s.press(float("nan"), 1.0)
    with pytest.raises(ValueError, match="sigma"):
        Session(*synthetic_pendulum(size=16, n_background=2), sigma=0.0)


def test_render_state_reset_and_initial_state():
    ae, chart, model = synthetic_pendulum()
    s = Session(ae, chart, model, initial="held_out", render_scale=2.0)
    first = int(np.flatnonzero(chart.split == 1)[0])
    assert s.state()["q"] == pytest.approx(chart.q[first].tolist(), abs=1e-6)
    assert s.state()["qdot"][0] != 0.0
    img = s.render()
    assert img.dtype == np.uint8 and img.shape == (128, 128, 3)
    assert s.dt == pytest.approx(1 / 30)
    json.dumps(s.state())
    s.reset()
    assert s.state()["dist_rest"] == 0.0 and s.state()["qdot"] == [0.0]
    pts = torch.tensor([[32.0, 44.0], [3.0, 60.0], [500.0, 500.0]])
    sel = s.transport.select(s.q_rest.expand(3, -1), pts, s.sigma)
    torch.testing.assert_close(s.brush_jacobians(pts), torch.einsum("pk,kid->pid", sel.weights, s.transport.J))
    # the most mobile point lies on the bob (the synthetic pendulum's bob centre is at (32, 44))
    x, y = s.most_mobile_point()
    assert abs(x - 32) < 6 and abs(y - 44) < 6


def test_view_stage_serves_the_toy_and_stops_after_max_seconds(capsys):
    if not _have_toy():
        pytest.skip(f"the trained toy system is missing ({TOY}: run `snakemake -c2 toy`)")
    from lagsplat.cli import main

    assert main(["view", "system=toy", f"results_dir={ROOT / 'results'}", "view.port=0", "view.max_seconds=0.5"]) == 0
    out = capsys.readouterr().out
    assert "lagsplat view: toy at http://127.0.0.1:" in out


def test_view_stage_reports_missing_artifacts_and_busy_ports(tmp_path, capsys):
    from lagsplat.cli import main
    from lagsplat.viewer.server import bind_socket

    assert main(["view", "system=toy", f"results_dir={tmp_path}"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not found" in err[0] and err[0].startswith("lagsplat view: error:")
    sock = bind_socket("127.0.0.1", 0)
    try:
        with pytest.raises(ValueError, match="cannot listen"):
            bind_socket("127.0.0.1", sock.getsockname()[1])
    finally:
        sock.close()


# ---------------------------------------------------------------- the page, headless Chromium
def _playwright_or_skip():
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.skip("playwright is not installed (pip install playwright)")
    if not Path(CHROMIUM).exists():
        pytest.skip(f"no Chromium at {CHROMIUM} (apt-get update && apt-get install -y chromium)")
    return sync_playwright


def test_page_drag_moves_the_model_and_release_lets_it_settle(tmp_path):
    _playwright_or_skip()
    s = _session("toy" if _have_toy() else "synthetic")
    with served_page(s) as (page, viewer, url):
        st = json.loads(urllib.request.urlopen(url + "state", timeout=10).read())
        assert st["size"] == [s.width, s.height]
        # the sliders reach the session: damping 4x and inertia 0.25x (log2 sliders) settle quickly
        page.locator("#damping").fill("2")
        page.locator("#inertia").fill("-2")
        page.wait_for_function("window.lagsplatState.params.damping === 4 && window.lagsplatState.params.inertia === 0.25", timeout=10_000)
        assert s.params["damping"] == 4.0 and s.params["inertia"] == 0.25

        box = page.locator("#view").bounding_box()
        kx, ky = box["width"] / s.width, box["height"] / s.height
        x, y = s.most_mobile_point()
        page.mouse.move(box["x"] + x * kx, box["y"] + y * ky)
        page.mouse.down()
        page.mouse.move(box["x"] + (x + DRAG_PX) * kx, box["y"] + y * ky, steps=8)
        page.wait_for_function("window.lagsplatState.grab !== null && window.lagsplatState.dist_rest > 0", timeout=10_000)
        page.wait_for_timeout(1500)
        held = page.evaluate("JSON.parse(JSON.stringify(window.lagsplatState))")
        assert held["grab"] is not None and held["dragging"]
        assert held["grab"]["pointer"][0] == pytest.approx(x + DRAG_PX, abs=0.5)
        assert held["grab"]["point"][0] > x + 0.25 * DRAG_PX - 2 * s.sigma  # the material was pulled right
        d_held = held["dist_rest"]
        assert d_held > 0.02
        shot = tmp_path / "screenshot.png"
        page.screenshot(path=str(shot))
        page.mouse.up()
        page.wait_for_function(f"window.lagsplatState.grab === null && window.lagsplatState.dist_rest < {0.1 * d_held}", timeout=20_000)
        final = page.evaluate("JSON.parse(JSON.stringify(window.lagsplatState))")
        assert final["stats"]["sim_hz"] > 5 and final["pageFps"] > 1
        assert "Hz" in page.locator("#stats").inner_text()
        page.locator("#reset").click()
        page.wait_for_function("window.lagsplatState.dist_rest < 1e-4 && window.lagsplatState.grab === null", timeout=10_000)
        # at 900 px width every status line wraps inside the page instead of being cut off
        page.set_viewport_size({"width": 900, "height": 800})
        for el in ("#stats", "#qline", "#status"):
            fits = page.evaluate(f"(() => {{ const e = document.querySelector('{el}'); const r = e.getBoundingClientRect(); "
                                 f"return e.scrollWidth <= e.clientWidth + 1 && r.right <= window.innerWidth; }})()")  # fmt: skip
            assert fits, f"{el} is cut off at 900 px"
        stats = page.locator("#stats").inner_text()
        assert "ms per frame" in stats and "frames/s possible" in stats and "frames/s shown" in stats
    assert shot.stat().st_size > 0  # kept in pytest's tmp_path for a human to look at; never in the user's results/


def test_the_rollout_figure_states_its_key_metrics_in_plain_words() -> None:
    """The figure's title line names the metrics it shows; entries absent from a protocol are left out."""
    from lagsplat.viz.rollout import held_out_frequency, metrics_line

    m = {"eps_freq": {"value": 0.0123}, "eps_q": {"value": 0.051}, "eps_I_over_AE": {"value": 2.5}, "f_enc_hz": {"value": 0.8}}
    assert metrics_line(m) == "eps_freq 1.23%, eps_q 0.051, eps_I / eps_AE 2.50  (held-out frames)"
    assert metrics_line({"mse_0p5s": {"value": 1.5e-3}, "eps_freq": {"value": None}}) == "MSE(0.5 s) 1.50e-03  (held-out frames)"
    # the calibrated 90 % intervals where metrics.json has them; none where it has no interval
    with_iv = {**m, "f_sim_hz": {"value": 0.79}, "f_sim_hz_interval": {"value": [0.77, 0.81]}, "zeta_sim": {"value": 0.01},
               "zeta_sim_interval": {"value": None}}  # fmt: skip
    assert metrics_line(with_iv) == "eps_freq 1.23%, eps_q 0.051, eps_I / eps_AE 2.50, f 0.790 Hz [0.770, 0.810]  (held-out frames)"
    assert held_out_frequency(m) == 0.8  # the soft-robot protocol writes no f_enc_segment_hz
    assert held_out_frequency({"f_enc_segment_hz": {"value": 0.7}, **m}) == 0.7
    # held-out frames at rest: no encoded frequency, the model's slowest mode instead
    assert held_out_frequency({"f_enc_hz": {"value": None}, "f_modes_hz": {"value": [1.4, 0.6, None]}}) == 0.6
    with pytest.raises(ValueError, match="f_enc_segment_hz, f_enc_hz or f_modes_hz"):
        held_out_frequency({"eps_q": {"value": 0.1}})


# ---------------------------------------------------------------- the page's text and layout, without a browser
PAGE = ROOT / "lagsplat" / "viewer" / "static" / "index.html"


def test_the_stats_say_what_each_number_measures() -> None:
    """Render time per frame (and the rate it would allow), frames sent and frames shown are separate numbers.

    A 90.8 ms render with 28.3 frames/s sent used to read "render 28.3 fps (90.8 ms/frame)". The page's
    text functions (pure functions of a state object) run under node."""
    import shutil
    import subprocess

    node = shutil.which("node")
    if node is None:
        pytest.skip("node is not installed (the page's text functions run under node)")
    html = PAGE.read_text(encoding="utf-8")
    functions = html[html.index("// ---- status text:") : html.index("// ---- end of status text")]
    st = {
        "stats": {"sim_hz": 30.0, "render_fps": 28.3, "realtime": 1.0}, "dt": 1 / 30, "render_ms": 11.0, "pageFps": 27.9,
        "step_ms": 0.25, "substeps": 1, "compiled": True, "t": 1.5, "q": [0.1, -0.2], "dist_rest": 0.2236,
        "grab": {"force": [1.2, -3.0], "seen_px": 0.4},
    }  # fmt: skip
    js = functions + f"\nconst st = {json.dumps(st)};\nconsole.log(JSON.stringify([statsText(st), qText(st)]));\n"
    r = subprocess.run([node, "-e", js], capture_output=True, text=True, timeout=60, check=False)
    assert r.returncode == 0, r.stderr
    stats, q = json.loads(r.stdout)
    assert stats.splitlines() == [
        "simulation 30.0 Hz (target 30.0, 100% real time)",
        "render     11.0 ms per frame (91 frames/s possible), 28.3 frames/s sent",
        "page       27.9 frames/s shown",
        "step 0.25 ms (1 sub-step, compiled), t = 1.50 s",
    ]
    assert q == ("q = [0.100, -0.200]  |q - q_rest| = 0.224  force (1.2, -3.0) px; held material moved 0.40 px rms in training"
                 " (barely seen moving: its response is extrapolated)")  # fmt: skip


def test_the_status_lines_wrap_instead_of_being_cut_off_at_900_px() -> None:
    """The page's CSS, read without a browser (the browser test measures the laid-out page at 900 px).

    Every status line may wrap (no ``white-space: pre`` / ``nowrap``) and breaks long words, and the
    image plus the panel's minimum width fit side by side in a 900 px window."""
    import re

    html = PAGE.read_text(encoding="utf-8")
    css = html[html.index("<style>") + len("<style>") : html.index("</style>")]
    rules = {sel.strip(): body for sels, body in re.findall(r"([^{}]+)\{([^}]*)\}", css) for sel in sels.split(",")}
    for el in ("#stats", "#qline", "#status"):
        assert "overflow-wrap: anywhere" in rules[el] and not re.search(r"white-space:\s*(pre|nowrap)\s*;", rules[el]), el

    def px(sel: str, prop: str) -> int:
        return int(re.search(rf"(?:^|[;\s]){prop}:\s*(\d+)px", rules[sel]).group(1))

    border = 2 * px("#view", "border")
    assert 2 * px("body", "margin") + px("#view", "width") + border + px("#wrap", "gap") + px("#panel", "min-width") <= 900


def test_the_websocket_accepts_only_its_own_page():
    """Any page open in the user's browser could drive the model through ws://127.0.0.1:<port>/ws; only the
    viewer's own page (same Origin and Host, a loopback Host) or a client that sends no Origin may connect."""
    import asyncio

    import aiohttp

    from lagsplat.viewer.server import Viewer, same_origin

    assert same_origin("http://127.0.0.1:8765", "127.0.0.1:8765", 8765)
    assert same_origin(None, "localhost:8765", 8765)
    assert not same_origin("https://example.com", "127.0.0.1:8765", 8765)  # another site's page
    assert not same_origin("http://127.0.0.1:8765", "127.0.0.1:9999", 8765)
    assert not same_origin("http://evil.example:8765", "evil.example:8765", 8765)  # DNS rebinding to 127.0.0.1
    viewer = Viewer(Session(*synthetic_pendulum()), port=0)
    url = viewer.start()
    host = url.split("//")[1].rstrip("/")

    async def status(origin: str | None) -> int:
        headers = {"Origin": origin} if origin else {}
        async with aiohttp.ClientSession() as http:
            try:
                async with http.ws_connect(url + "ws", headers=headers) as ws:
                    await ws.close()
                    return 101
            except aiohttp.WSServerHandshakeError as exc:
                return exc.status

    try:
        assert asyncio.run(status("https://example.com")) == 403
        assert asyncio.run(status(f"http://{host}")) == 101
        assert asyncio.run(status(None)) == 101
    finally:
        viewer.stop()
