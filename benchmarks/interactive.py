"""Frame rate of the interactive viewer (``python -m lagsplat view``): simulation + render per second.

Times a :class:`~lagsplat.viewer.session.Session` (batch 1) on these systems:

* ``toy``: the trained toy system (``results/toy``; 1024 Gaussians, 64x64), at its
  own resolution and re-rendered at 128x128 (``render_scale=2``);
* ``toy x2``: the same decoder with every primitive duplicated (2048 Gaussians,
  positions jittered by ~0.3 px), rendered at 128x128;
* ``synthetic``: the hand-built pendulum of :mod:`lagsplat.viewer.synthetic` at
  128x128 with a 44x44 tiled background (2001 Gaussians); used alone when
  ``results/toy`` is missing.

Per system, free and while dragging (a held grab at the most mobile point,
the pointer 8 px to the side): one simulation step (``dt`` of simulated time,
sub-steps included), one render (decode to uint8 RGB), one PNG encode, and
the viewer's per-frame work in sequence (step + render + encode), as
steps per second (median of ``--repeats`` timed calls after one warm-up).

``--page`` (default on when Playwright and ``/usr/bin/chromium`` are
present) also serves each 128x128 session with the real :class:`Viewer`
and loads the page in headless Chromium: simulation Hz, server render fps
and frames drawn per second by the page over ``--seconds``, free and while
the mouse drags. The simulation is real-time (one step per ``dt``: 30 Hz for
these 30 fps clips), so its Hz is capped at ``1 / dt``; render and page fps
are capped by it too (one frame per new state).

Usage::

    python benchmarks/interactive.py [--threads 2] [--repeats 5] [--no-page]

Writes what it prints to ``results/benchmarks/interactive.md`` (``--report PATH``, ``--no-report``).

The target is >= 30 Hz (goal 60) at 128x128 with about 2000 Gaussians.

The 3-D viewer (``python -m lagsplat view`` on a 3-D system; viser draws the splats in the browser) is timed
on the trained 3-D system at ``--model3d`` (default ``results/pendulum3d``, made by ``snakemake -c2
results/pendulum3d/metrics.json``) and on the same decoder with every primitive duplicated (``x2``): one
simulation step, the splats handed to viser, one render of an orbit view at 128x128 by the CPU rasteriser
(the ``render`` stage's path; its rate is step + render, no PNG: viser is sent splats, not images), and the
server's frames sent per second (step + splats + send, real time: capped at ``1 / dt``). With ``--page`` the
viser page is loaded in headless Chromium at 128x128 (WebGL in software, SwiftShader, on these cores) while
the server moves the client's camera along an orbit: frames drawn per second by the page
(``requestAnimationFrame``), viser's own frame-rate reading, and the server's frames sent per second; then
again with ``view.render_3d=server`` (a ", server render" row: the server renders the browser's camera at
128 px with the decoder's rasteriser and sends the image; its frames/s is the rate of new renders shown).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing
from _common import Report, add_report_options, env_header, shown_path, time_call

from lagsplat.viewer.browser import CHROMIUM

ROOT = Path(__file__).resolve().parents[1]


def _parse(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--threads", type=int, default=2, help="torch threads")
    ap.add_argument("--repeats", type=int, default=5, help="timed calls per measurement (median reported)")
    ap.add_argument("--steps", type=int, default=10, help="steps (or frames) per timed call")
    ap.add_argument("--toy", type=Path, default=ROOT / "results" / "toy", help="trained toy system folder")
    ap.add_argument("--model3d", type=Path, default=ROOT / "results" / "pendulum3d", help="trained 3-D system folder")
    ap.add_argument("--page", dest="page", action="store_true", default=None, help="also measure the served page in headless Chromium")
    ap.add_argument("--no-page", dest="page", action="store_false")
    ap.add_argument("--seconds", type=float, default=4.0, help="measurement window of each page run")
    add_report_options(ap, "interactive")
    return ap.parse_args(argv)


def _doubled(ae, jitter_px: float = 0.3, seed: int = 0):
    """A copy of ``ae`` whose decoder (2-D or 3-D) holds every primitive twice (positions jittered by ~``jitter_px``)."""
    import torch

    from lagsplat.models.autoencoder import AutoEncoder

    src = ae.decoder
    dec = type(src)(2 * src.K, src.d, backend=src.backend, background=tuple(src.background.tolist()), **src.options())
    per_primitive = {n for n, _ in src.named_parameters() if "." not in n}
    dec.load_state_dict({k: (torch.cat([v, v]) if k in per_primitive else v) for k, v in src.state_dict().items()})
    with torch.no_grad():
        g = torch.Generator().manual_seed(seed)
        if src.n_space == 3:  # world units: jitter_px at the middle of the depth range
            step = jitter_px * float(sum(src.depth_range)) / 2.0 / src.camera.fx
        else:  # mu_s = 1.2 sigmoid(mu_raw) - 0.1: d mu_s / d mu_raw <= 0.3 (normalised units)
            step = jitter_px / (0.3 * max(ae.height, ae.width))
        dec.mu_raw[src.K :] += torch.randn(src.K, src.n_space, generator=g) * step
    return AutoEncoder(ae.encoder, dec, ae.height, ae.width).eval()


def _sessions3d(args, note=print):
    """``[(name, Session3D)]`` of the trained 3-D system and its doubled decoder, or ``[]`` (``note`` says why)."""
    from lagsplat.artifacts import Artifacts
    from lagsplat.viewer.viewer3d import Session3D

    a = Artifacts.at(args.model3d)
    if not all(p.exists() for p in (a.stage1, a.chart, a.stage2)):
        note(f"({shown_path(args.model3d)} has no trained 3-D system: the 3-D viewer is not timed; `snakemake -c2 results/pendulum3d/metrics.json` makes one)")
        return []
    ae, chart = a.load_stage1(), a.load_chart()
    model, _ = a.load_stage2()
    name = args.model3d.name
    return [(name, Session3D(ae, chart, model)), (f"{name} x2", Session3D(_doubled(ae), chart, model))]


def _orbit(session, n: int, size: int = 128):
    """``n`` cameras evenly around a full orbit through the main camera, about where it looks, ``size`` pixels square."""
    from lagsplat.render.camera import orbit_through
    from lagsplat.viewer.viewer3d import main_camera_pose

    return orbit_through(session.ae.decoder.camera, main_camera_pose(session)["look_at"], n, size, size)


def _rows3d(args, page: bool) -> list[dict]:
    """The 3-D viewer's timings (module docstring)."""
    import torch

    from lagsplat.viewer.viewer3d import served_viser

    rows = []
    for name, s in _sessions3d(args):
        dec = s.ae.decoder
        cams = _orbit(s, 72)[: args.steps]
        with torch.no_grad():
            dec.render(s.chart.to_raw(s.q), 128, 128, camera=cams[0])  # compilation / cache load outside the timings
            t_step = time_call(lambda: s.step(args.steps), args.repeats) / args.steps
            t_splats = time_call(lambda: [s.splats() for _ in range(args.steps)], args.repeats) / args.steps
            t_render = time_call(lambda: [dec.render(s.chart.to_raw(s.q), 128, 128, camera=c) for c in cams], args.repeats) / args.steps
        row = {"system": name, "gaussians": dec.K, "size": "128x128", "drag": "orbit", "sub-steps": 1, "step ms": f"{t_step * 1e3:.1f}",
               "render ms": f"{t_render * 1e3:.1f}", "png ms": "-", "splats ms": f"{t_splats * 1e3:.1f}", "step+render+png Hz": f"{1 / (t_step + t_render):.0f}"}  # fmt: skip
        for render in ("browser", "server") if page else ("browser",):
            frames = [0]
            s.reset()
            r = dict(row) if render == "browser" else {**{k: "-" for k in row}, "system": f"{name}, server render", "gaussians": dec.K,
                                                         "size": "128x128", "drag": "orbit", "render ms": row["render ms"]}  # fmt: skip
            with served_viser(s, on_frame=lambda _srv: frames.__setitem__(0, frames[0] + 1), render=render) as (url, server):
                f0, t1 = frames[0], time.perf_counter()
                time.sleep(2.0)
                r["server frames/s"] = f"{(frames[0] - f0) / (time.perf_counter() - t1):.1f}"
                if page:
                    r.update(_viser_page_rates(s, url, server, frames, args.seconds))
            rows.append(r)
            print(f"  done: {r}", flush=True)
    return rows


def _viser_page_rates(session, url: str, server, frames: list, seconds: float) -> dict:
    """Open the viser page at 128x128 in headless Chromium (software WebGL) while the server moves its camera around
    the orbit through the main camera at 30 degrees per second."""
    from playwright.sync_api import sync_playwright

    from lagsplat.viewer.browser import CHROMIUM_WEBGL_ARGS
    from lagsplat.viewer.viewer3d import main_camera_pose, wait_for_client

    orbit, target = _orbit(session, 120), tuple(main_camera_pose(session)["look_at"])  # cameras 3 degrees apart
    fps_logged: list[float] = []
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_WEBGL_ARGS, headless=True)
        try:
            page = browser.new_page(viewport={"width": 128, "height": 128})
            page.on("console", lambda m: fps_logged.extend(float(x.split("/")[0]) for x in m.text.split("FPS=")[1:2]) if "FPS=" in m.text else None)
            page.goto(url)
            page.wait_for_function("document.querySelector('canvas') !== null", timeout=60_000)
            client = wait_for_client(server)
            page.wait_for_timeout(1500)
            page.evaluate("() => { window.__rafs = 0; const f = () => { window.__rafs++; requestAnimationFrame(f); }; requestAnimationFrame(f); }")
            n0, f0, t0 = page.evaluate("window.__rafs"), frames[0], time.perf_counter()
            while (t := time.perf_counter() - t0) < seconds:
                cam = orbit[int(10.0 * t) % len(orbit)]
                with client.atomic():
                    client.camera.position = tuple(cam.center)
                    client.camera.look_at = target
                page.wait_for_timeout(33)
            wall = time.perf_counter() - t0
            n1, f1 = page.evaluate("window.__rafs"), frames[0]
        finally:
            browser.close()
    return {"page: sim Hz": f"{(f1 - f0) / wall:.1f}", "page: render fps": f"{(n1 - n0) / wall:.1f}", "page: page fps": f"{fps_logged[-1]:.0f}" if fps_logged else "-"}


def _sessions(args, note=print):
    """``[(name, Session)]`` of the configurations measured; ``note`` gets the line saying when the toy is missing."""
    from lagsplat.viewer.session import Session
    from lagsplat.viewer.synthetic import synthetic_pendulum

    out = []
    from lagsplat.artifacts import Artifacts

    a = Artifacts.at(args.toy)
    if all(p.exists() for p in (a.stage1, a.chart, a.stage2)):
        ae, chart = a.load_stage1(), a.load_chart()
        model, _ = a.load_stage2()
        out.append(("toy", Session(ae, chart, model)))
        out.append(("toy", Session(ae, chart, model, render_scale=2.0)))
        out.append(("toy x2", Session(_doubled(ae), chart, model, render_scale=2.0)))
    else:
        note(f"({shown_path(args.toy)} has no trained toy system: synthetic pendulum only)")
    out.append(("synthetic", Session(*synthetic_pendulum(size=128, n_background=44))))
    return out


def _page_rates(session, seconds: float, drag: bool) -> dict:
    """Serve ``session`` and read the page's rates in headless Chromium (free or while dragging)."""
    from lagsplat.viewer.browser import served_page

    session.reset()
    with served_page(session, timeout_ms=60_000) as (page, viewer, _url):
        box = page.locator("#view").bounding_box()
        kx, ky = box["width"] / session.width, box["height"] / session.height
        x, y = session.most_mobile_point()
        if drag:
            page.mouse.move(box["x"] + x * kx, box["y"] + y * ky)
            page.mouse.down()
        page.wait_for_timeout(1000)  # warm-up
        n0, s0, r0, t0 = page.evaluate("window.lagsplatState.framesReceived"), session.steps, viewer.frames_rendered, time.perf_counter()
        k = 0
        while time.perf_counter() - t0 < seconds:
            if drag:  # keep the pointer moving: 8 px to the side and back
                k += 1
                page.mouse.move(box["x"] + (x + 8 * (k % 2)) * kx, box["y"] + y * ky, steps=4)
            page.wait_for_timeout(100)
        wall = time.perf_counter() - t0
        n1, s1, r1 = page.evaluate("window.lagsplatState.framesReceived"), session.steps, viewer.frames_rendered
        if drag:
            page.mouse.up()
    return {"sim Hz": (s1 - s0) / wall, "render fps": (r1 - r0) / wall, "page fps": (n1 - n0) / wall}


def main(argv: list[str] | None = None):
    args = _parse(argv)
    import lagsplat  # noqa: F401, I001  (first: sets GOMP_SPINCOUNT before torch starts its threads)
    import torch

    from lagsplat.viewer.server import encode_image

    torch.set_num_threads(args.threads)
    page = args.page
    if page is None:
        try:
            import playwright  # noqa: F401

            page = Path(CHROMIUM).exists()
        except ImportError:
            page = False
    import numba

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    rep = Report("Interactive viewer: simulation and render rates", args.report, __file__, argv)
    print(env_header(f"numba {numba.__version__}, {numba.config.NUMBA_NUM_THREADS} threads") + f"; load average {load:.1f}")
    rep.text(
        f"batch 1; median of {args.repeats} timed calls of {args.steps} steps after one warm-up; drag: 8 px at the most mobile point; "
        + (f"page: headless Chromium, {args.seconds:g} s per run, 128x128 sessions only" if page else "page not measured")
    )

    rows = []
    for name, s in _sessions(args, rep.text):
        s.render()  # numba compilation / cache load outside the timings
        base = {"system": name, "gaussians": s.ae.decoder.K, "size": f"{s.render_width}x{s.render_height}"}
        x, y = s.most_mobile_point()
        for drag in (False, True):
            s.reset()
            if drag:
                s.press(x, y)
                s.move(x + 8.0, y)
            n = args.steps
            t_step = time_call(lambda s=s, n=n: s.step(n), args.repeats) / n
            t_render = time_call(lambda s=s, n=n: [s.render() for _ in range(n)], args.repeats) / n
            img = s.render()
            t_png = time_call(lambda img=img, n=n: [encode_image(img, "png") for _ in range(n)], args.repeats) / n

            def frame(s=s, n=n):
                for _ in range(n):
                    s.step()
                    im, _ = s.snapshot()
                    encode_image(im, "png")

            t_frame = time_call(frame, args.repeats) / n
            row = {
                **base,
                "drag": "yes" if drag else "no",
                "sub-steps": s.state()["substeps"],
                "step ms": f"{t_step * 1e3:.1f}",
                "render ms": f"{t_render * 1e3:.1f}",
                "png ms": f"{t_png * 1e3:.2f}",
                "step+render+png Hz": f"{1 / t_frame:.0f}",
                "diverged": s.diverged,
            }
            if page and s.render_width >= 128:
                r = _page_rates(s, args.seconds, drag)
                row.update({f"page: {k}": f"{v:.1f}" for k, v in r.items()})
            rows.append(row)
            print(f"  done: {row}", flush=True)
        s.release()
    rows += _rows3d(args, page)
    page_cols = [k for r in rows for k in r if k.startswith("page: ")]
    for r in rows:
        r.setdefault("splats ms", "-")
        r.setdefault("server frames/s", "-")
    for r in rows:  # the page is measured at 128x128 only
        for k in dict.fromkeys(page_cols):
            r.setdefault(k, "-")
    table = rep.table(rows)
    rep.write()
    return table


if __name__ == "__main__":
    main()
