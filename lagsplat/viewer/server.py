"""The viewer's local web server: live render over a websocket, pointer events back.

``python -m lagsplat view system=<name>`` (see :func:`lagsplat.stages_report.stage_view`)
builds a :class:`~lagsplat.viewer.session.Session` and serves it with a
:class:`Viewer` on ``http://127.0.0.1:<port>/`` (loopback only).

Threads. The simulation and the renderer run in two threads of their own so
that a slow render never slows simulated time:

* simulation: one :meth:`Session.step` (``dt`` simulated seconds) per ``dt``
  of wall time; when a step overruns, the schedule is re-anchored rather than
  letting a backlog build (``realtime`` in the page's statistics falls below 1);
* renderer: renders the *latest* state whenever the simulation has advanced
  (or a press, release, reset or slider change came in) and a page is connected (every step if it keeps up, otherwise the states in
  between are skipped), encodes PNG (or JPEG) and hands the frame to the
  event loop;
* event loop (aiohttp): serves the page, sends each connected page the newest
  frame, at most two frames in flight per page (the page acknowledges each
  frame it has drawn; a slow page gets fewer frames, never a backlog).

Wire format (websocket ``/ws``). Server -> page: one binary message per frame,
``uint32 big-endian n`` + ``n`` bytes of UTF-8 JSON (``Session.state()`` plus
``frame``, ``format`` and ``stats`` ``{"sim_hz", "render_fps", "realtime"}``)
+ the encoded image (``render_size`` px). ``sim_hz``: simulation steps per
second; ``render_fps``: frames rendered and sent per second, paced by the
simulation and the page's acknowledgements, so not ``1000 / render_ms``
(``render_ms``, in the session's state, is the time one render takes); the page
shows both, and the frames per second it draws itself. Page -> server: JSON text,
``{"type": "press" | "move", "x", "y"}`` (training-resolution pixels),
``{"type": "release"}``, ``{"type": "reset"}``,
``{"type": "params", "inertia"?, "damping"?, "stiffness"?, "force_scale"?}``,
``{"type": "ack"}``.

Also ``GET /state`` (JSON) and ``GET /frame.png`` (the current render).
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import json
import socket
import struct
import threading
import time
from importlib import resources

import numpy as np

from lagsplat.viewer.session import Session

__all__ = ["Session", "Viewer", "bind_socket", "encode_image", "same_origin", "LOOPBACK_NAMES"]

_IN_FLIGHT = 2  # frames sent but not yet acknowledged by a page


def encode_image(img: np.ndarray, fmt: str = "png") -> bytes:
    """uint8 RGB ``[H,W,3]`` -> PNG (fast compression) or JPEG (quality 90) bytes.

    Raises:
        ValueError: on an unknown format.
    """
    import cv2

    bgr = np.ascontiguousarray(img[:, :, ::-1])
    if fmt == "png":
        ok, buf = cv2.imencode(".png", bgr, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    elif fmt in ("jpeg", "jpg"):
        ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, 90])
    else:
        raise ValueError(f"image format must be 'png' or 'jpeg', got {fmt!r}")
    if not ok:
        raise ValueError(f"could not encode a {img.shape} image as {fmt}")
    return buf.tobytes()


LOOPBACK_NAMES = ("127.0.0.1", "localhost", "[::1]")
"""The host names the viewer answers to (it binds to the loopback interface only)."""


def same_origin(origin: str | None, host: str | None, port: int) -> bool:
    """Whether a WebSocket handshake comes from the viewer's own page.

    A browser sends ``Origin`` with every WebSocket handshake, so any page open in the user's browser could
    otherwise connect to ``ws://127.0.0.1:<port>/ws`` and drive the model. Accepted: a ``Host`` naming the
    loopback interface at the viewer's ``port`` (:data:`LOOPBACK_NAMES`; a page on another name that resolves to
    127.0.0.1, DNS rebinding, is refused), and an ``Origin`` that is absent (not a browser: a script, a test) or
    ``http://<that Host>``. RFC 6455 §10.2 (origin considerations).

    Args:
        origin: the ``Origin`` header, or ``None``.
        host: the ``Host`` header (``name:port``).
        port: the port the viewer listens on.
    """
    if not host:
        return False
    name, _, p = host.rpartition(":")
    if name not in LOOPBACK_NAMES or p != str(port):
        return False
    return origin is None or origin.rstrip("/") == f"http://{host}"


def bind_socket(host: str, port: int) -> socket.socket:
    """A listening TCP socket on ``host:port`` (``port`` 0: any free port).

    Raises:
        ValueError: if the address cannot be bound (port in use, ...), with the cause in one line.
    """
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    try:
        sock.bind((host, int(port)))
        sock.listen(16)
    except OSError as exc:
        sock.close()
        raise ValueError(f"cannot listen on {host}:{port}: {exc.strerror or exc}; choose another view.port (0 = any free port)") from None
    sock.setblocking(False)
    return sock


class _Rate:
    """Events per second over a sliding window of ``window`` seconds (one thread ticks, any thread reads)."""

    def __init__(self, window: float = 1.0) -> None:
        self.window, self.times = window, collections.deque(maxlen=1024)

    def tick(self) -> None:
        self.times.append(time.perf_counter())

    def rate(self) -> float:
        now = time.perf_counter()
        recent = [t for t in list(self.times) if now - t <= self.window]
        if len(recent) < 2:
            return 0.0
        return (len(recent) - 1) / max(recent[-1] - recent[0], 1e-9)


class Viewer:
    """Serve a :class:`Session` on a local web page.

    Args:
        session: the simulation to show and drive.
        host: interface to bind; loopback only (``127.0.0.1``, ``localhost`` or ``::1``).
        port: TCP port; 0 picks a free one (read :attr:`url` after start).
        image_format: ``"png"`` or ``"jpeg"`` frames.

    Use :meth:`serve` (blocking, the CLI) or :meth:`start` / :meth:`stop`
    (a background thread, tests and benchmarks).

    Raises:
        ValueError: on a non-loopback host or an unknown image format.
    """

    def __init__(self, session: Session, host: str = "127.0.0.1", port: int = 8765, image_format: str = "png") -> None:
        if host not in ("127.0.0.1", "localhost", "::1"):
            raise ValueError(f"the viewer binds to the loopback interface only, got host {host!r}")
        if image_format not in ("png", "jpeg"):
            raise ValueError(f"image format must be 'png' or 'jpeg', got {image_format!r}")
        self.session, self.host, self.port, self.image_format = session, "127.0.0.1" if host == "localhost" else host, int(port), image_format
        self.url: str | None = None
        self._stop = threading.Event()
        self._advanced = threading.Event()
        self._ready = threading.Event()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop_future: asyncio.Future | None = None
        self._clients: dict[int, dict] = {}
        self._latest: tuple[int, bytes] | None = None
        self._sim_rate, self._render_rate = _Rate(), _Rate()
        self._realtime = 1.0
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self.frames_rendered = 0

    # ------------------------------------------------------------ worker threads
    def _sim_loop(self) -> None:
        s = self.session
        next_t = time.perf_counter()
        window = collections.deque(maxlen=64)
        while not self._stop.is_set():
            s.step()
            now = time.perf_counter()
            window.append(now)
            if len(window) > 1 and window[-1] > window[0]:
                self._realtime = (len(window) - 1) * s.dt / (window[-1] - window[0])
            self._sim_rate.tick()
            self._advanced.set()
            next_t += s.dt
            delay = next_t - time.perf_counter()
            if delay > 0:
                self._stop.wait(delay)
            elif delay < -0.1:  # overran by more than 100 ms: give the time up instead of catching up in a burst
                next_t = time.perf_counter()

    def _render_loop(self) -> None:
        while not self._stop.is_set():
            if not self._advanced.wait(0.1):
                continue
            self._advanced.clear()
            if not self._clients:
                continue
            img, st = self.session.snapshot()
            self.frames_rendered += 1
            self._render_rate.tick()
            st["frame"] = self.frames_rendered
            st["format"] = self.image_format
            st["stats"] = {"sim_hz": self._sim_rate.rate(), "render_fps": self._render_rate.rate(), "realtime": self._realtime}
            head = json.dumps(st).encode()
            payload = struct.pack(">I", len(head)) + head + encode_image(img, self.image_format)
            loop = self._loop
            if loop is not None and not loop.is_closed():
                with contextlib.suppress(RuntimeError):  # loop closing
                    loop.call_soon_threadsafe(self._publish, self.frames_rendered, payload)

    # ------------------------------------------------------------ event loop side
    def _publish(self, seq: int, payload: bytes) -> None:
        self._latest = (seq, payload)
        for c in self._clients.values():
            c["new"].set()

    async def _index(self, request):
        from aiohttp import web

        html = resources.files("lagsplat.viewer").joinpath("static/index.html").read_text(encoding="utf-8")
        return web.Response(text=html, content_type="text/html", headers={"Cache-Control": "no-store"})

    async def _state(self, request):
        from aiohttp import web

        st = self.session.state()
        st["stats"] = {"sim_hz": self._sim_rate.rate(), "render_fps": self._render_rate.rate(), "realtime": self._realtime}
        return web.json_response(st)

    async def _frame(self, request):
        from aiohttp import web

        loop = asyncio.get_running_loop()
        img = await loop.run_in_executor(None, self.session.render)
        return web.Response(body=encode_image(img, "png"), content_type="image/png", headers={"Cache-Control": "no-store"})

    def _handle(self, msg: dict) -> None:
        s, kind = self.session, msg.get("type")
        if kind == "press":
            s.press(float(msg["x"]), float(msg["y"]))
        elif kind == "move":
            s.move(float(msg["x"]), float(msg["y"]))
        elif kind == "release":
            s.release()
        elif kind == "reset":
            s.reset()
        elif kind == "params":
            s.set_params(**{k: float(msg[k]) for k in ("inertia", "damping", "stiffness", "force_scale") if msg.get(k) is not None})
        else:
            raise ValueError(f"unknown message type {kind!r}")
        if kind != "move":  # show a press, release, reset or new setting without waiting for the next step
            self._advanced.set()

    async def _ws(self, request):
        from aiohttp import WSMsgType, web

        if not same_origin(request.headers.get("Origin"), request.host, self.port):
            raise web.HTTPForbidden(text="the viewer's WebSocket accepts its own page only (Origin and Host differ, or Host is not loopback)")
        ws = web.WebSocketResponse(compress=False, heartbeat=20.0)
        await ws.prepare(request)
        client = {"new": asyncio.Event(), "credits": asyncio.Semaphore(_IN_FLIGHT), "ws": ws}
        self._clients = {**self._clients, id(client): client}  # replaced, never mutated: the renderer reads it

        async def sender() -> None:
            last = -1
            while not ws.closed:
                await client["new"].wait()
                client["new"].clear()
                if self._latest is None or self._latest[0] == last:
                    continue
                await client["credits"].acquire()
                seq, payload = self._latest  # the newest frame at the time a credit is free
                last = seq
                await ws.send_bytes(payload)

        task = asyncio.create_task(sender())
        try:
            async for msg in ws:
                if msg.type != WSMsgType.TEXT:
                    continue
                try:
                    m = json.loads(msg.data)
                    if m.get("type") == "ack":
                        client["credits"].release()
                        continue
                    self._handle(m)
                except (ValueError, KeyError, TypeError) as exc:
                    await ws.send_str(json.dumps({"error": str(exc)}))
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, ConnectionError):
                await task
            self._clients = {k: v for k, v in self._clients.items() if k != id(client)}
        return ws

    async def _main(self, max_seconds: float | None, on_ready) -> None:
        from aiohttp import web

        self._loop = asyncio.get_running_loop()
        self._stop_future = self._loop.create_future()
        app = web.Application()
        app.router.add_get("/", self._index)
        app.router.add_get("/index.html", self._index)
        app.router.add_get("/ws", self._ws)
        app.router.add_get("/state", self._state)
        app.router.add_get("/frame.png", self._frame)
        runner = web.AppRunner(app, handle_signals=False, access_log=None, shutdown_timeout=1.0)
        await runner.setup()
        try:
            sock = bind_socket(self.host, self.port)
            site = web.SockSite(runner, sock)
            await site.start()
            port = self.port = sock.getsockname()[1]  # the port bound (port 0: the one the system chose)
            host = f"[{self.host}]" if ":" in self.host else self.host
            self.url = f"http://{host}:{port}/"
            workers = [threading.Thread(target=f, name=f"lagsplat-view-{n}", daemon=True) for n, f in (("sim", self._sim_loop), ("render", self._render_loop))]
            for w in workers:
                w.start()
            self._ready.set()
            if on_ready is not None:
                on_ready(self.url)
            try:
                await asyncio.wait_for(asyncio.shield(self._stop_future), timeout=max_seconds)
            except asyncio.TimeoutError:
                pass
            finally:
                self._stop.set()
                for c in list(self._clients.values()):
                    with contextlib.suppress(Exception):
                        await c["ws"].close()
                for w in workers:
                    await self._loop.run_in_executor(None, w.join, 5.0)
        finally:
            await runner.cleanup()

    # ------------------------------------------------------------ public
    def serve(self, max_seconds: float | None = None, on_ready=None) -> None:
        """Serve until :meth:`stop`, ``max_seconds`` of wall time, or Ctrl-C (blocking).

        Args:
            max_seconds: stop after this many seconds (``None``: no limit).
            on_ready: called with the URL once the server listens.

        Raises:
            ValueError: if the port cannot be bound.
        """
        try:
            asyncio.run(self._main(max_seconds, on_ready))
        except KeyboardInterrupt:
            pass
        finally:
            self._stop.set()
            self._ready.set()

    def start(self, timeout: float = 30.0) -> str:
        """Serve from a background thread; returns the URL once listening.

        Raises:
            ValueError: if the port cannot be bound.
            TimeoutError: if the server is not up within ``timeout`` seconds.
        """

        def run() -> None:
            try:
                self.serve()
            except BaseException as exc:  # noqa: BLE001  (re-raised by start())
                self._error = exc
                self._ready.set()

        self._thread = threading.Thread(target=run, name="lagsplat-view-server", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout):
            raise TimeoutError(f"the viewer did not start within {timeout} s")
        if self._error is not None:
            raise self._error
        return self.url  # type: ignore[return-value]

    def stop(self, timeout: float = 10.0) -> None:
        """Stop serving (from any thread) and wait for the server thread started by :meth:`start`."""
        self._stop.set()
        loop, fut = self._loop, self._stop_future
        if loop is not None and fut is not None and not loop.is_closed():
            with contextlib.suppress(RuntimeError):
                loop.call_soon_threadsafe(lambda: fut.done() or fut.set_result(None))
        if self._thread is not None:
            self._thread.join(timeout)

