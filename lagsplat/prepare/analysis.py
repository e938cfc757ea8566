"""The motion analysis behind automatic preparation: is there an object, is it of the model's class, where is it.

:func:`analyse_motion` reads grey frames at the analysis resolution and

* measures the sensor noise and stops a clip in which nothing moves;
* finds the moving parts and chooses the oscillating object among them
  (:mod:`lagsplat.prepare.parts`), dropping the others (people, hands, doors);
* checks the *object* (not the dropped parts) against the model class: it
  stays in the frame (its foreground shrinks at the border in at most 5 % of
  the frames) and it oscillates rather than turning about a point
  (:func:`image_winding`);
* gives the region of interest (the box holding the object's changing pixels,
  moving shadows included), its typical size, and its frequency over the
  frames where it moves (:mod:`lagsplat.prepare.frequency`).

Every refusal is a :class:`PreparationRefused` (a ``ClipError``) whose one line
names the file, what was seen, and the setting that would change the decision
(``crop``, ``frames``); it carries what the analysis had found, for the preview.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.ndimage import binary_dilation, binary_opening, gaussian_filter, label

from lagsplat.io.clip import ClipError
from lagsplat.prepare.frequency import harmonic_share
from lagsplat.prepare.parts import choose_object, find_parts

__all__ = ["PreparationRefused", "analyse_motion", "image_winding", "CHANGE_FRACTION", "KEEP_SHARE", "ROTATION_TURNS", "ROTATION_SHARE", "MAX_LEAVING"]

#: A pixel of the object changes when its temporal standard deviation reaches this share of the object's largest.
CHANGE_FRACTION = 0.15
#: Within the object's region, a changing blob is kept when its summed standard deviation reaches this share of the largest's.
KEEP_SHARE = 0.3
#: A rotation (:func:`image_winding`): at least this many net turns of the object's image, and this share of all its
#: turning. Every oscillation of the realistic suite and the real clips stays well below both
#: (docs/experiments/code_comment_history.md).
ROTATION_TURNS, ROTATION_SHARE = 2.0, 0.5
#: A pixel of a part kept with the object changes with the object's rhythm when its power at the object's frequency
#: and harmonics holds this share (:func:`periodic_pixels`).
PIXEL_SHARE = 0.25
#: The object may shrink at the image border in at most this share of the frames.
MAX_LEAVING = 0.05


class PreparationRefused(ClipError):
    """A clip that automatic preparation stops on; ``analysis`` holds what had been found (for the preview)."""

    def __init__(self, message: str, analysis: dict[str, Any]):
        super().__init__(message)
        self.analysis = analysis


def _bounds(mass: np.ndarray, share: float = 0.005) -> tuple[int, int]:
    """``[lo, hi)`` indices holding all but ``share`` of ``mass`` at each end (robust to stray changing pixels)."""
    c = np.cumsum(mass) / max(float(mass.sum()), 1e-12)
    return int(np.searchsorted(c, share)), int(np.searchsorted(c, 1.0 - share)) + 1


def _out_of_frame(touches: np.ndarray, small: np.ndarray) -> float:
    """Share of frames in which the object is (partly) out of the frame.

    A frame counts when the object's foreground is small and it touches the border, or when it is
    small within a run of small frames that begins or ends at a frame touching the border (the
    object left, and came back, there; an object at rest merges with the static scene too, but
    not at the border).
    """
    out = small & touches
    t, T = 0, len(small)
    while t < T:
        if not small[t]:
            t += 1
            continue
        end = t
        while end < T and small[end]:
            end += 1
        if (t > 0 and touches[t - 1]) or (end < T and touches[end]) or touches[t:end].any():
            out[t:end] = True
        t = end
    return float(out.mean())


def image_winding(x: np.ndarray, changing: np.ndarray) -> tuple[float, float]:
    """How the image of the moving part turns: ``(net_turns, total_turns)`` of its two leading principal components.

    The frames' changing pixels (grey ``x [T,h,w]``, mask ``changing [h,w]``) are projected on
    their first two principal components; the angle of that 2-D path about its centre is
    unwrapped (steps where the path passes near the centre, below 0.3 of its median radius, are
    left out). An oscillation retraces an arc, so its net turning stays within about a turn
    however long the clip; an object turning about a point (a wheel, a disc spinning down)
    goes round in one direction: ``|net|`` close to ``total`` and growing with the clip.
    """
    P = x[:, changing].astype(np.float64)
    if P.shape[1] < 2 or P.shape[0] < 3:
        return 0.0, 0.0
    P -= P.mean(0)
    U, S, _ = np.linalg.svd(P, full_matrices=False)
    s1, s2 = U[:, 0] * S[0], U[:, 1] * S[1]
    r = np.hypot(s1, s2)
    step = np.diff(np.unwrap(np.arctan2(s2, s1)))
    far = (r[1:] > 0.3 * np.median(r)) & (r[:-1] > 0.3 * np.median(r))
    return float(step[far].sum() / (2 * np.pi)), float(np.abs(step[far]).sum() / (2 * np.pi))


def periodic_pixels(x: np.ndarray, region: np.ndarray, frequency_hz: float, dt: float) -> np.ndarray:
    """The pixels of ``region`` whose intensity changes with the object's rhythm, ``[h, w]`` bool.

    A pixel the object or its shadow passes over changes once or twice a period; a person beside it does not. Per
    pixel, the share of its intensity's power (over ``x [n, h, w]``, the frames where the object moves; Hann window)
    within two resolution bins of the frequency and of its multiples (a small, fast object passes a pixel as a short
    pulse, whose power spreads over many harmonics), above what a flat spectrum puts there, must reach
    :data:`PIXEL_SHARE`. All of ``region`` is kept when there are fewer than 8 frames or the frequency is unknown.
    """
    n = x.shape[0]
    if n < 8 or not np.isfinite(frequency_hz) or frequency_hz <= 0 or not region.any():
        return region
    ys, xs = np.nonzero(region)
    v = x[:, ys, xs].astype(np.float64)
    power = np.abs(np.fft.rfft((v - v.mean(0)) * np.hanning(n)[:, None], axis=0)) ** 2  # [n//2 + 1, m]
    share = harmonic_share(power, np.fft.rfftfreq(n, dt), frequency_hz, 2.0 / (n * dt))
    keep = np.zeros_like(region)
    keep[ys[share >= PIXEL_SHARE], xs[share >= PIXEL_SHARE]] = True
    return keep


def _dropped_text(dropped: list, w: int, h: int) -> list[str]:
    return [f"a part {p.where(w, h)} (x {p.box[0]}-{p.box[2]}, y {p.box[1]}-{p.box[3]} of {w}x{h}): {p.verdict}" for p in dropped]


def noise_floor(x: np.ndarray) -> float:
    """The sensor-noise level of grey frames ``x [T,h,w]`` in [0, 1]: the median frame-to-frame change of a
    pixel, read where the scene is still (the 25th percentile over pixels, over sqrt 2), at least half a grey level."""
    return max(float(np.percentile(np.abs(np.diff(x, axis=0)).mean(0), 25)) / np.sqrt(2.0), 0.5 / 255.0)


def analyse_motion(frames: np.ndarray, src: str = "<clip>", dt: float = 1.0 / 30.0) -> dict[str, Any]:
    """Motion statistics of uint8 ``[T,h,w,3]`` frames at the analysis resolution (module docstring).

    Args:
        frames: the clip (or the user's crop of it), uint8 ``[T, h, w, 3]``.
        src: the file, named in every error.
        dt: frame interval, s.

    Returns:
        ``{"box": (x0, y0, x1, y1) in these frames' pixels (exclusive end), "snr", "changing" [h,w] bool (the
        object's changing pixels), "object_area" (median foreground pixels per frame), "leaving_fraction",
        "frequency_hz", "peak_share", "span" (start, stop) frames where the object moves, "periods" (over that
        span), "path" [stop - start] px, "parts" (every :class:`lagsplat.prepare.parts.Part`), "kept", "dropped"
        (sentences), "note" (or None), "frames" (the input)}``.

    Raises:
        PreparationRefused: naming ``src`` and the setting to change: fewer than 8 frames, nothing moves above
            the noise, or a motion outside the model class (a dissipative Lagrangian about a rest state): the
            object leaves the frame in more than :data:`MAX_LEAVING` of the frames, or it turns about a point
            (:func:`image_winding`, :data:`ROTATION_TURNS`).
    """
    out: dict[str, Any] = {"frames": frames, "parts": [], "dropped": [], "note": None}
    if frames.ndim != 4 or frames.shape[0] < 8:
        raise PreparationRefused(f"{src}: automatic preparation needs at least 8 frames, got {frames.shape[0]} (set `frames` to a longer range)", out)
    x = frames.astype(np.float32).mean(-1) / 255.0  # [T,h,w] grey
    T, h, w = x.shape
    std = gaussian_filter(x.std(0), 1.0)
    floor = noise_floor(x)
    top = float(std.max())
    snr = top / floor
    out["snr"] = snr
    if snr < 4.0:
        raise PreparationRefused(
            f"{src}: nothing moves: the largest temporal change is {255 * top:.1f} grey levels, {snr:.1f}x the noise floor (need 4x); "
            "check `frames` (the range may miss the motion) and `crop`",
            out,
        )
    bg = np.median(x, axis=0)
    parts = find_parts(x, std, floor, dt)
    out["parts"] = parts
    if parts:
        kept, dropped, note = choose_object(parts)
        obj = kept[0]
        # a part kept for moving with the object (its shadow) may hold, joined to it in space, something that moves on
        # its own (a person beside the shadow): of such a part, only the pixels that change with the object's rhythm
        others = [p.region & periodic_pixels(x[obj.span[0] : obj.span[1]], p.region, obj.frequency_hz, dt) for p in kept[1:]]
        region = binary_dilation(np.logical_or.reduce([obj.region] + others), iterations=2)  # the box's
        reach = binary_dilation(np.logical_or.reduce([p.region for p in kept]), iterations=2)  # where it can leave the frame
        out.update(dropped=_dropped_text(dropped, w, h), dropped_parts=dropped, note=note, kept=kept, frequency_hz=obj.frequency_hz, peak_share=obj.peak_share,
                   span=obj.span, periods=obj.periods, path=obj.path)  # fmt: skip
    else:  # nothing stands out as a part (a faint, spread change): the whole frame
        region = reach = np.ones((h, w), bool)
        out.update(kept=[], frequency_hz=float("nan"), peak_share=0.0, span=(0, T), periods=0.0, path=np.zeros(T))
    # the static scene: the median frame; for an object that comes to rest, the median over the frames where it moves
    # (else it sits in the median where it rests, and vanishes from its own foreground while at rest)
    a, b = out["span"]
    if b - a < 0.9 * T and b - a >= 8:
        bg = np.median(x[a:b], axis=0)
    # the object's changing pixels: its standard deviation against its own largest (so a stronger dropped part sets
    # no threshold), blobs carrying a good share of the largest blob's change (compression flicker drops out)
    top_obj = float(std[region].max()) if region.any() else top
    changing = binary_opening((std > max(CHANGE_FRACTION * top_obj, 3.0 * floor)) & region, iterations=1)
    if not changing.any():
        changing = (std >= 0.5 * top_obj) & region
    labels, n = label(binary_dilation(changing, iterations=2), structure=np.ones((3, 3)))
    mass = np.bincount(labels[changing], weights=std[changing], minlength=n + 1)
    keep = mass >= KEEP_SHARE * mass.max()
    keep[0] = False
    changing = changing & keep[labels]
    weight = np.where(changing, std, 0.0)
    (bx0, bx1), (by0, by1) = _bounds(weight.sum(0)), _bounds(weight.sum(1))
    out.update(box=(bx0, by0, bx1, by1), changing=changing)
    # per-frame foreground of the object: where the frame departs from the static scene by more than the noise
    dev = np.abs(x - bg) * region[None]
    fg = dev > max(6.0 * floor, 0.25 * top_obj)
    area = fg.sum((1, 2)).astype(float)
    out["object_area"] = float(np.median(area[area > 0])) if (area > 0).any() else 0.0
    # the border band: 2 px, or as far as the object moves in one frame (a fast object can leave between two frames)
    step = float(np.percentile(np.hypot(*np.diff(out["kept"][0].xy, axis=0).T), 95)) if out["kept"] else 0.0
    b = int(np.clip(np.ceil(step), 2, max(2, 0.1 * min(h, w))))
    border = np.zeros((h, w), bool)
    border[:b], border[-b:], border[:, :b], border[:, -b:] = True, True, True, True
    # whether the object leaves: its foreground against the departure noise of the frames from the static scene
    # (compression leaves still blocks unchanged from frame to frame, so the frame-to-frame floor above can miss the
    # sensor noise a departure carries), and its spatial extent
    dev_noise = 1.4826 * float(np.median(np.abs(x - bg)))
    fg_obj = np.abs(x - bg) * reach[None] > max(4.0 * dev_noise, 6.0 * floor, 0.25 * top_obj)
    area_obj = binary_opening(fg_obj, iterations=1, structure=np.ones((1, 2, 2))).sum((1, 2)).astype(float)  # without noise specks
    med_obj = float(np.median(area_obj[area_obj > 0])) if (area_obj > 0).any() else 0.0
    touches = (fg_obj & border).sum((1, 2)) > 0  # a sliver at the border counts
    leaving = _out_of_frame(touches, area_obj < 0.3 * med_obj) if med_obj > 0 else 0.0
    out["leaving_fraction"] = leaving
    dropped = f"; {len(out['dropped'])} other moving part(s) set aside" if out["dropped"] else ""
    if leaving > MAX_LEAVING:
        raise PreparationRefused(
            f"{src}: outside the model class: the moving object leaves the frame (it shrinks at the image border in "
            f"{100 * leaving:.0f}% of the frames, at most {100 * MAX_LEAVING:.0f}%{dropped}); if the object stays in view, set `crop` "
            "around it; if it leaves only in part of the recording, set `frames` to where it stays in view",
            out,
        )
    net, total = image_winding(x, changing)
    if abs(net) >= ROTATION_TURNS and abs(net) >= ROTATION_SHARE * total:
        raise PreparationRefused(
            f"{src}: outside the model class: the object turns about a point ({abs(net):.1f} turns of its image in one direction, "
            f"{100 * abs(net) / total:.0f}% of its turning), a rotation, not an oscillation about a rest state{dropped}; "
            "if another part of the frame is the oscillating object, set `crop` around it",
            out,
        )
    return out
