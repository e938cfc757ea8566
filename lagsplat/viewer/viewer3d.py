"""The 3-D viewer: orbit an identified 3-D model in the browser (viser) and push it in any direction.

:class:`Session3D` holds one latent state ``(q, qdot)`` of a 3-D system (Stage-1 autoencoder with the 3-D
decoder, frozen chart, Stage-2 Lagrangian) and advances it by velocity Verlet
(:func:`~lagsplat.dynamics.integrators.verlet_step`) in steps of the clip's frame interval. A click casts a
ray (origin and direction in world units, as viser reports it): the material the ray meets first is
selected (:meth:`lagsplat.forces.transport3d.ForceTransport3D.select`, through a virtual camera on the ray) and a
world-space force of ``force`` world units along the ray (a push into depth) or opposite to it (a pull)
acts on it, pulled back as ``kappa sum_i w_i J_i^T f`` (paper Eq. 9, §4.5), until released.

:func:`serve_viser` shows the model at the current state with viser's orbit camera (each browser starts at
the main camera's pose: :func:`main_camera_pose`) and a panel: force, push / pull, release, reset. Two ways
to draw it: ``render="browser"`` sends the Gaussians as splats
(``viser.SceneApi.add_gaussian_splats``: world means, covariances, colours, opacities times the latent gate)
and the browser draws them (fast with a GPU); ``render="server"`` renders each browser's camera with the
decoder's own rasteriser (:meth:`Session3D.render`, the image Stage 1 trained) and sends it as the page's
background image, so the browser only shows a picture (a CPU-only machine, software WebGL, a remote server).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Callable

import numpy as np
import torch

from lagsplat.dynamics.integrators import initial_state, verlet_step
from lagsplat.forces.transport import Selection
from lagsplat.forces.transport3d import ForceTransport3D
from lagsplat.io.clip import HELD_OUT
from lagsplat.render.camera import Camera, look_at

__all__ = ["Session3D", "main_camera_pose", "client_camera", "serve_viser", "served_viser", "wait_for_client"]


class Session3D:
    """One simulation of an identified 3-D system (thread-safe).

    Args:
        ae: the Stage-1 autoencoder with the 3-D decoder.
        chart: its frozen chart.
        model: the Stage-2 Lagrangian.
        force: magnitude of a push, world units (> 0), or ``"auto"``: the force whose generalized force, on the
            median primitive's Jacobian, moves the state by half a chart unit against the stiffest direction of
            the potential at rest (``0.5 lambda_max(hess V) / median_i |J_i|``).
        kappa: energy factor of forces (:func:`lagsplat.forces.transport.calibrate_kappa`).

    Raises:
        ValueError: if the decoder is not a 3-D one, or ``force <= 0``.
    """

    def __init__(self, ae, chart, model, force: float | str = "auto", kappa: float = 1.0) -> None:
        self.ae, self.chart, self.model = ae, chart, model
        self.ft = ForceTransport3D.from_autoencoder(ae, chart, min_transmittance=0.5)
        self.dt = float(np.median(np.diff(chart.t)))
        if force == "auto":
            k = float(torch.linalg.eigvalsh(model.potential_hessian(model.q_rest.detach()[None]).reshape(self.ft.d, self.ft.d).double()).max())
            force = 0.5 * max(k, 1e-9) / max(float(torch.linalg.matrix_norm(self.ft.J, ord=2).median()), 1e-9)
        if not float(force) > 0:
            raise ValueError(f"force must be positive, got {force}")
        self.force, self.kappa = float(force), float(kappa)
        self.geom = ae.decoder.geometry()
        self._lock = threading.Lock()
        self._sel: Selection | None = None
        self._dir = torch.zeros(1, 3)
        self.reset()

    def reset(self) -> None:
        """Back to the first held-out frame's encoded state and velocity (or the first frame's), no force."""
        held = np.flatnonzero(self.chart.split == HELD_OUT)
        i = int(held[0]) if len(held) and held[0] + 2 < len(self.chart.q) else 0
        q0, v0 = initial_state(self.chart.q, np.array([i]), self.dt)
        with self._lock:
            self.q, self.qdot, self._sel = q0.float(), v0.float(), None

    def press_ray(self, origin, direction, sign: float = 1.0) -> bool:
        """Select the material the ray ``origin + s direction`` (world, ``[3]`` each) meets first and push it along
        ``sign * direction``. Returns whether the ray met anything."""
        o, d = np.asarray(origin, float), np.asarray(direction, float)
        d = d / np.linalg.norm(d)
        up = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
        cam = look_at(o, o + d, up, 65, 65, 5.0)  # a narrow virtual camera on the ray: the ray is its centre pixel
        with self._lock:
            sel = self.ft.select(self.q, cam, torch.tensor([32.5, 32.5]), sigma=1.0)
            hit = float(sel.weights.sum()) > 0
            self._sel = sel if hit else None
            self._dir = torch.as_tensor(sign * d, dtype=torch.float32)[None]
        return hit

    @property
    def pushing(self) -> bool:
        """Whether a push acts now (a ray met material and nothing released it)."""
        return self._sel is not None

    @property
    def push_direction(self) -> np.ndarray:
        """Unit world direction ``[3]`` of the last push (the click's ray, reversed for a pull)."""
        return self._dir[0].numpy().astype(float)

    def release(self) -> None:
        """Stop pushing."""
        with self._lock:
            self._sel = None

    def generalized_force(self) -> torch.Tensor | None:
        """The push's generalized force ``[1,d]``, or ``None`` when nothing is pushed."""
        if self._sel is None:
            return None
        return self.ft.pullback(self._sel, self.force * self._dir, self.kappa)

    @torch.no_grad()
    def step(self, n: int = 1) -> None:
        """Advance ``n`` frame intervals under the current push."""
        with self._lock:
            f = self.generalized_force()
            for _ in range(n):
                self.q, self.qdot = verlet_step(self.model, self.q, self.qdot, self.dt, f_ext=f)

    @torch.no_grad()
    def splats(self) -> dict[str, np.ndarray]:
        """The Gaussians at the current state, as viser takes them: ``centers [K,3]``, ``covariances [K,3,3]``,
        ``rgbs [K,3]``, ``opacities [K,1]`` (base opacity times the latent gate, paper Eq. 4)."""
        with self._lock:
            q = self.q.clone()
        g = self.geom
        means, gate, _ = self.ae.decoder.condition(self.chart.to_raw(q), g)
        op = g.alpha[None] * gate
        return {"centers": means[0].numpy(), "covariances": g.cov.numpy(), "rgbs": g.colors.numpy(), "opacities": op[0, :, None].numpy()}

    @torch.no_grad()
    def render(self, camera: Camera) -> np.ndarray:
        """uint8 ``[H,W,3]`` image of the model at the current state through ``camera`` (the decoder's rasteriser)."""
        from lagsplat.viz.novel_views import novel_view_frames

        with self._lock:
            q = self.q.clone()
        return novel_view_frames(self.ae.decoder, self.chart.to_raw(q), [camera], camera.height, camera.width)[0]


def main_camera_pose(session: Session3D) -> dict[str, object]:
    """The main (filmed) camera as viser's client camera: ``position`` (its centre, world units), ``look_at`` (the
    point on its optical axis at the middle of the decoder's depth range), ``up_direction`` (image up, ``-R[1]``)
    and ``fov`` (vertical field of view, radians, ``2 atan(H / 2 f_y)``)."""
    cam = session.ae.decoder.camera
    R = np.asarray(cam.R, float)
    depth = float(np.mean(session.ae.decoder.depth_range))
    c = np.asarray(cam.center, float)
    return {"position": tuple(c), "look_at": tuple(c + depth * R[2]), "up_direction": tuple(-R[1]), "fov": float(2.0 * np.arctan(cam.height / (2.0 * cam.fy)))}


def client_camera(handle, height: int = 128) -> Camera:
    """The :class:`Camera` of a viser client's camera ``handle`` (OpenCV axes: ``P_world = R_wc p_cam + position``,
    vertical field of view ``fov``), imaging ``height`` pixels high at the browser's aspect ratio, square pixels.

    Raises:
        ValueError: if ``height < 1``.
    """
    import viser.transforms as vtf

    if height < 1:
        raise ValueError(f"height must be >= 1, got {height}")
    R = vtf.SO3(np.asarray(handle.wxyz, float)).as_matrix().T  # world -> camera
    width = max(1, int(round(height * float(handle.aspect))))
    f = 0.5 * height / np.tan(0.5 * float(handle.fov))
    return Camera(width, int(height), f, f, width / 2.0, height / 2.0, tuple(map(tuple, R)), tuple(-R @ np.asarray(handle.position, float)))


def serve_viser(
    session: Session3D, port: int = 8080, max_seconds: float | None = None, on_ready: Callable[[str], None] | None = None,
    stop: threading.Event | None = None, on_frame: Callable[[object], None] | None = None, render: str = "browser",
    size: int = 128,
):  # fmt: skip
    """Serve ``session`` with viser on ``http://127.0.0.1:<port>/`` until Ctrl-C, ``max_seconds`` or ``stop`` is set;
    returns the server (stopped). Each browser that connects starts at the main camera's pose
    (:func:`main_camera_pose`) and orbits with viser's mouse controls; clicking the model pushes it along the
    click's ray (module docstring). ``render``: ``"browser"`` (splats) or ``"server"`` (this process renders each
    browser's camera, ``size`` pixels high; module docstring). ``on_ready(url)`` is called once serving,
    ``on_frame(server)`` after each frame was sent (e.g. to count frames).

    Raises:
        ModuleNotFoundError: with the install line, if viser is missing.
        ValueError: for another ``render``.
    """
    if render not in ("browser", "server"):
        raise ValueError(f"render must be 'browser' or 'server', got {render!r}")
    try:
        import viser
    except ModuleNotFoundError as e:
        raise ModuleNotFoundError("the 3-D viewer needs viser: pip install 'lagsplat[viewer3d]' (or pip install viser)") from e
    server = viser.ViserServer(host="127.0.0.1", port=int(port), verbose=False)
    R = np.asarray(session.ae.decoder.camera.R, float)
    server.scene.set_up_direction(tuple(-R[1]))  # the main camera's image up
    force = server.gui.add_slider("force (world units)", min=0.01, max=10.0 * session.force, step=0.01, initial_value=session.force)
    pull = server.gui.add_checkbox("pull instead of push", initial_value=False)
    release, reset = server.gui.add_button("release"), server.gui.add_button("reset")
    status = server.gui.add_markdown("click the model to push it along your line of sight")

    @force.on_update
    def _(_e) -> None:
        session.force = float(force.value)

    @release.on_click
    def _(_e) -> None:
        session.release()

    @reset.on_click
    def _(_e) -> None:
        session.reset()

    pose = main_camera_pose(session)

    @server.on_client_connect
    def _(client) -> None:
        with client.atomic():
            client.camera.fov = pose["fov"]
            client.camera.position = pose["position"]
            client.camera.up_direction = pose["up_direction"]
            client.camera.look_at = pose["look_at"]

    @server.scene.on_click()
    def _(event) -> None:
        hit = session.press_ray(event.ray_origin, event.ray_direction, -1.0 if pull.value else 1.0)
        status.content = "pushing (release stops)" if hit else "the ray met nothing"

    if on_ready is not None:
        on_ready(f"http://127.0.0.1:{server.get_port()}/")
    t_end = None if max_seconds is None else time.monotonic() + float(max_seconds)
    try:
        deadline = time.monotonic()
        while (t_end is None or time.monotonic() < t_end) and not (stop is not None and stop.is_set()):
            session.step()
            if render == "browser":
                server.scene.add_gaussian_splats("/model", **session.splats())
            else:
                for client in list(server.get_clients().values()):
                    try:
                        cam = client_camera(client.camera, size)
                    except AssertionError:  # the browser has not reported its camera yet
                        continue
                    client.scene.set_background_image(session.render(cam), format="jpeg")
            if on_frame is not None:
                on_frame(server)
            deadline += session.dt  # real time, paced by deadlines (sleep overshoots would otherwise add up)
            wait = deadline - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            else:  # behind: start afresh rather than rush to catch up
                deadline = time.monotonic()
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
    return server


@contextmanager
def served_viser(session: Session3D, timeout_s: float = 30.0, on_frame: Callable[[object], None] | None = None,
                 render: str = "browser") -> Iterator[tuple[str, object]]:  # fmt: skip
    """:func:`serve_viser` on a free localhost port in a background thread; yields ``(url, server)`` once the first
    frame was sent and stops the server on exit (tests, benchmarks). ``on_frame`` and ``render`` as in :func:`serve_viser`.

    Raises:
        RuntimeError: if no frame was sent within ``timeout_s``.
    """
    urls: list[str] = []
    servers: list[object] = []
    stop = threading.Event()

    def frame(server) -> None:
        if not servers:
            servers.append(server)
        if on_frame is not None:
            on_frame(server)

    th = threading.Thread(target=serve_viser, args=(session, 0), kwargs={"on_ready": urls.append, "stop": stop, "on_frame": frame, "render": render},
                          daemon=True)  # fmt: skip
    th.start()
    try:
        t0 = time.monotonic()
        while not (urls and servers) and th.is_alive() and time.monotonic() - t0 < timeout_s:
            time.sleep(0.05)
        if not (urls and servers):
            raise RuntimeError(f"viser sent no frame within {timeout_s:g} s")
        yield urls[0], servers[0]
    finally:
        stop.set()
        th.join(10)


def wait_for_client(server, timeout_s: float = 30.0):
    """The first browser connected to the viser ``server`` (its client handle: camera, GUI).

    Raises:
        TimeoutError: if none connects within ``timeout_s``.
    """
    t0 = time.monotonic()
    while not server.get_clients():
        if time.monotonic() - t0 > timeout_s:
            raise TimeoutError(f"no browser connected to the viewer within {timeout_s:g} s")
        time.sleep(0.05)
    return next(iter(server.get_clients().values()))
