"""The soft-robot surrogate as a file: the ``.npz`` of the published recordings' layout and its truth sidecar JSON.

Part of :mod:`lagsplat.synth.continuum_robot` (its docstring describes the model).
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from lagsplat.io.atomic import atomic_write
from lagsplat.synth._render import (
    SUPERSAMPLE,
    check_supersample,
    parse_size,
)
from lagsplat.synth.continuum_robot.constants import DEFAULT_DURATION_S, DT, FPS
from lagsplat.synth.continuum_robot.model import (
    ContinuumRobot,
    check_segments,
    pressure_keys,
)
from lagsplat.synth.continuum_robot.pressure import PressureSchedule
from lagsplat.synth.continuum_robot.render import render_continuum_robot
from lagsplat.synth.continuum_robot.simulate import n_frames_for, simulate_frames


def _jsonable(x: Any) -> Any:
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    return x


def write_robot_npz(
    path: str | os.PathLike[str],
    n_segments: int,
    duration_s: float = DEFAULT_DURATION_S,
    seed: int = 0,
    *,
    size: Sequence[int] = (32, 32),
    supersample: int = SUPERSAMPLE,
    n_substeps: int = 4,
    robot: dict[str, Any] | None = None,
    **schedule_kwargs: Any,
) -> dict[str, Any]:
    """Simulate, render and write the surrogate clip in the Krauss NPZ layout, with a sidecar JSON.

    The NPZ (``np.savez_compressed``) holds exactly ``images`` float32
    ``(T, 3, H, W)`` in [0, 1] (uint8 / 255, so multiples of 1/255) and one
    float32 ``(T,)`` array per chamber, ``p1, p2`` (one segment) or
    ``p1..p4`` (two), normalised by 101 325 Pa, like the real recordings. The
    metadata goes to ``<path>.json`` (e.g. ``robot_2seg.npz.json``)::

        n_segments, fps (60000/1001), dt (1001/60000 s), n_frames, duration_s,
        f_natural_hz   small-amplitude natural frequencies of the depressurised
                       robot (linearisation about q_rest), ascending
        zeta           their damping ratios; f_damped_hz  f sqrt(1 - zeta^2)
        head_frames    leading frames with all pressures zero (robot at rest)
        tail_start_frame  first frame of the depressurised tail (all later
                       pressures exactly zero)
        rest_frames    [[start, stop), ...] mid-clip zero-pressure intervals
        n_train_frames int(train_fraction T), the consumer's split
        pressure_keys, chambers, coordinates, q_rest, linearisation
        (mass, stiffness, damping, rayleigh, mode_shapes), seed, source,
        params: {robot, schedule, render, integration}

    Both files are written atomically (temporary file in the same folder,
    then ``os.replace``); on any failure neither is left behind in part.

    Args:
        path: output ``.npz`` path (parent folders are created).
        n_segments: 1 or 2.
        duration_s: clip length (s; default 150 s = 8991 frames).
        seed: seeds the pressures and the background texture.
        size: ``(W, H)`` pixels (default the Krauss 32 x 32).
        supersample: anti-aliasing factor of the renderer.
        n_substeps: RK4 steps per frame.
        robot: overrides of :meth:`ContinuumRobot.default` (e.g. ``{"zeta": 0.05}``).
        **schedule_kwargs: keyword arguments of :meth:`PressureSchedule.random`.

    Returns:
        The metadata dict written to the JSON.

    Raises:
        ValueError: on invalid arguments (naming the argument), or a path not ending in ``.npz``.
        TypeError: if ``robot`` is not a dict.
    """
    out = Path(path)
    if out.suffix != ".npz":
        raise ValueError(f"{out}: the output path must end in .npz")
    n = check_segments(n_segments)
    if robot is not None and not isinstance(robot, dict):
        raise TypeError(f"robot must be a dict of ContinuumRobot.default overrides, got {type(robot).__name__}")
    rob = ContinuumRobot.default(n, **(robot or {}))
    W, H = parse_size(size, 16)
    s = check_supersample(supersample)
    sched = PressureSchedule.random(n, duration_s, seed, **schedule_kwargs)
    T = n_frames_for(sched.duration_s)
    states, pressures = simulate_frames(rob, sched, T, n_substeps)
    frames = render_continuum_robot(states[:, : rob.d], rob, (W, H), seed, s)
    images = np.ascontiguousarray(np.moveaxis(frames, -1, 1).astype(np.float32) / np.float32(255.0))
    keys = pressure_keys(n)
    arrays: dict[str, np.ndarray] = {"images": images}
    for c, k in enumerate(keys):
        arrays[k] = pressures[:, c].astype(np.float32)

    zero = np.all(pressures == 0.0, axis=1)
    head_frames = int(np.argmin(zero)) if not zero.all() else T
    nonzero = np.flatnonzero(~zero)
    tail_start = int(nonzero[-1] + 1) if nonzero.size else 0
    t_frames = np.arange(T) * DT
    rest_frames = []
    for t_rel, t_up in sched.rests:
        inside = np.flatnonzero(zero & (t_frames >= t_rel) & (t_frames <= t_up))
        if inside.size:
            rest_frames.append([int(inside[0]), int(inside[-1] + 1)])
    modal = rob.modal
    meta: dict[str, Any] = {
        "source": "lagsplat.synth.continuum_robot",
        "npz": out.name,
        "n_segments": n,
        "fps": FPS,
        "dt": DT,
        "n_frames": T,
        "duration_s": T * DT,
        "f_natural_hz": modal.f_natural_hz,
        "zeta": modal.zeta,
        "f_damped_hz": modal.f_damped_hz,
        "tail_start_frame": tail_start,
        "head_frames": head_frames,
        "rest_frames": rest_frames,
        "n_train_frames": int(sched.params["train_fraction"] * T),
        "seed": int(seed),
        "pressure_keys": keys,
        "pressure_units": "gauge pressure / 101325 Pa",
        "chambers": {k: f"segment {c // 2 + 1}, {'image-left (bends it right, theta grows)' if c % 2 == 0 else 'image-right (bends it left)'}" for c, k in enumerate(keys)},
        "coordinates": [f"{name}_{i + 1}" for i in range(n) for name in ("theta", "eps")],
        "q_rest": modal.q_rest,
        "linearisation": {
            "mass": modal.mass,
            "stiffness": modal.stiffness,
            "damping": modal.damping,
            "rayleigh_alpha_beta": list(modal.rayleigh),
            "mode_shapes": modal.mode_shapes,
        },
        "params": {
            "robot": rob.params(),
            "schedule": sched.params,
            "render": {"size": [W, H], "supersample": s},
            "integration": {"method": "rk4", "n_substeps": int(n_substeps)},
        },
    }
    meta = _jsonable(meta)
    text = json.dumps(meta, indent=2) + "\n"
    json_path = out.with_name(out.name + ".json")
    with atomic_write(out) as tmp_npz, atomic_write(json_path) as tmp_json:
        with open(tmp_npz, "wb") as fh:  # a file object: numpy must not append ".npz"
            np.savez_compressed(fh, **arrays)
        tmp_json.write_text(text)
        for tmp in (tmp_npz, tmp_json):  # mkstemp makes 0600 files; data files are world-readable
            os.chmod(tmp, 0o644)
    return meta


