"""Shared test set-up.

Importing lagsplat first sets ``GOMP_SPINCOUNT`` before torch starts
its OpenMP pool (see lagsplat/__init__.py): torch's spinning threads otherwise
starve the numba rasterizer's workers on a 2-core machine.
"""

import lagsplat  # noqa: F401  (must precede any torch import)
import pytest


@pytest.fixture(scope="module")
def one_torch_thread():
    """Run a module's tests with one torch thread, restoring the previous count afterwards.

    For modules working on tiny tensors: one thread avoids OpenMP hand-offs and
    is much faster (10-40x seen) than two on a loaded 2-core machine. Opt in
    with ``pytestmark = pytest.mark.usefixtures("one_torch_thread")``.
    """
    import torch

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture(scope="module")
def gl_ok():
    """Skip a test that renders with MuJoCo where MuJoCo or an offscreen GL context (EGL) is missing."""
    pytest.importorskip("mujoco")
    import numpy as np

    from lagsplat.synth.realistic.camera import render_frames

    try:
        render_frames("pendulum", np.zeros((1, 1)), 32, 32)
    except RuntimeError as exc:
        pytest.skip(f"no offscreen GL: {exc}")


def _tree(root):
    """``{relative path: (size, mtime_ns)}`` of every file under ``root``."""
    from pathlib import Path

    root = Path(root)
    return {str(p.relative_to(root)): (p.stat().st_size, p.stat().st_mtime_ns) for p in root.rglob("*") if p.is_file()} if root.is_dir() else {}


@pytest.fixture(scope="session", autouse=True)
def results_untouched():
    """Tests never write into the user's ``results/``: the session fails if any file there appeared or changed."""
    from pathlib import Path

    results = Path(__file__).resolve().parents[1] / "results"
    before = _tree(results)
    yield
    after = _tree(results)
    changed = sorted(k for k in after if before.get(k) != after[k]) + sorted(set(before) - set(after))
    assert not changed, f"tests wrote into {results}: {changed[:10]}"


@pytest.fixture(scope="session")
def load_benchmark():
    """A function that imports ``benchmarks/<name>.py`` as a module (the benchmark scripts are not a package)."""
    import importlib.util
    from pathlib import Path

    def load(name: str):
        path = Path(__file__).resolve().parents[1] / "benchmarks" / f"{name}.py"
        spec = importlib.util.spec_from_file_location(f"bench_{name}", path)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod

    return load


@pytest.fixture()
def http_folder(tmp_path_factory):
    """A real HTTP server on localhost (in a thread) serving a fresh folder: ``(root, base_url, gets)``.

    Put files under ``root`` and fetch ``f"{base_url}/{name}"``; ``gets`` lists the path of every GET the
    server answered, so a test can tell a cached file from a second download.
    """
    import http.server
    import threading

    root = tmp_path_factory.mktemp("www")
    gets: list[str] = []

    class Handler(http.server.SimpleHTTPRequestHandler):
        def __init__(self, *a, **kw):
            super().__init__(*a, directory=str(root), **kw)

        def do_GET(self):
            gets.append(self.path)
            super().do_GET()

        def log_message(self, *a):  # keep test output clean
            pass

    srv = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    th = threading.Thread(target=srv.serve_forever, daemon=True)
    th.start()
    yield root, f"http://127.0.0.1:{srv.server_address[1]}", gets
    srv.shutdown()
    srv.server_close()
