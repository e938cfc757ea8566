"""The moving parts of a recording, and which of them is the oscillating object.

People film an oscillator with other things moving in the frame: a hand that
releases the object, a person seated at the edge, a passer-by, a door. Each
is a *part*: a connected region of pixels whose temporal standard deviation
stands out of the sensor noise. Every part's own path (the centroid of its
departure from the static scene) is read over the frames where it moves, on
its principal direction (:mod:`lagsplat.prepare.frequency`). The object is
the part whose motion is an oscillation about a rest state: its periodogram
has a clear peak (:data:`MIN_PEAK_SHARE`) over at least
:data:`MIN_CHOICE_PERIODS` periods; among several, the one that oscillates
most clearly over the longest part of the clip (:meth:`Part.score`). A part that
moves with the object (its shadow, a rod and its bob when they split) is kept
with it (:data:`MOVES_WITH`); every other part is dropped, with the reason.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import binary_dilation, binary_opening, distance_transform_edt, label, maximum_filter1d

from lagsplat.prepare.frequency import moving_span, path_frequency, periods_held, principal_path

__all__ = ["Part", "find_parts", "choose_object", "MIN_PEAK_SHARE", "MIN_CHOICE_PERIODS", "MOVES_WITH", "PART_FRACTION"]

#: A pixel belongs to a candidate part when its temporal standard deviation reaches this share of the largest
#: (lower than the region of interest's threshold, so that an object weaker than a person in the frame is seen)...
PART_FRACTION = 0.06
#: ... and this multiple of the median pixel's standard deviation (most of a frame is still).
STILL_FACTOR = 1.5
#: Changing pixels closer than twice this share of the frame's long side belong to one part.
JOIN_RADIUS = 0.035
#: Parts whose summed standard deviation is below this share of the largest part's are noise specks.
MIN_PART_SHARE = 0.03
#: At most this many parts are read (the strongest).
MAX_PARTS = 8
#: Time bins of the pixels' activity profiles; a pixel moves briefly when this share of its activity falls in this
#: many consecutive bins (a quarter of the clip).
TIME_BINS, BRIEF_BINS, BRIEF_SHARE = 12, 3, 0.85
#: A pixel's frame-to-frame change is an event when it exceeds this multiple of the noise level (about 6 standard
#: deviations of the sensor noise: the noise alone makes none).
EVENT_NOISE = 8.0
#: ... and this grey level (10 of 255).
EVENT_MIN = 10.0 / 255.0
#: Blobs of a part carrying less than this share of its largest blob's change are dropped from it.
BLOB_SHARE = 0.3
#: An oscillation's periodogram peak holds at least this share of its path's power.
MIN_PEAK_SHARE = 0.35
#: An oscillation shows at least this many periods over the frames where it moves.
MIN_CHOICE_PERIODS = 1.5
#: A part moves with the object when its path correlates with the object's this much (absolute value).
MOVES_WITH = 0.6


@dataclass
class Part:
    """One moving part of a clip (analysis pixels).

    Attributes:
        label: its label in the part image.
        region: ``[h, w]`` bool, its pixels.
        box: ``(x0, y0, x1, y1)``, exclusive end.
        mass: summed temporal standard deviation over its pixels (intensity in [0, 1] times px).
        xy: ``[T, 2]`` centroid of its departure from the static scene, px.
        span: ``(start, stop)`` frames over which it moves (:func:`lagsplat.prepare.frequency.moving_span`).
        path: ``[stop - start]`` its centroid on the principal direction over that span, px.
        direction: ``[2]`` that unit direction ``(x, y)``.
        frequency_hz, peak_share, periods: :func:`lagsplat.prepare.frequency.path_frequency` on ``path``,
            and the periods it holds (at most half its turning points plus a half,
            :func:`lagsplat.prepare.frequency.periods_held`).
        touches_border: whether its pixels reach the frame's border.
        members: for a part that was split by time (:func:`_split_by_time`), the whole is a candidate too:
            the labels of its two sides; ``()`` otherwise.
        verdict: ``"object"``, ``"with object"`` or why it was dropped.
    """

    label: int
    region: np.ndarray
    box: tuple[int, int, int, int]
    mass: float
    xy: np.ndarray
    span: tuple[int, int]
    path: np.ndarray
    direction: np.ndarray
    frequency_hz: float
    peak_share: float
    periods: float
    touches_border: bool
    members: tuple[int, ...] = ()
    verdict: str = field(default="")

    @property
    def oscillates(self) -> bool:
        """A clear spectral peak over enough periods (:data:`MIN_PEAK_SHARE`, :data:`MIN_CHOICE_PERIODS`)."""
        return bool(self.peak_share >= MIN_PEAK_SHARE and self.periods >= MIN_CHOICE_PERIODS)

    def score(self, n_frames: int) -> float:
        """How clearly and how long it oscillates: its peak share times the square root of the share of the
        clip's frames over which it moves (a hand that waves for a second ranks below an object that swings
        throughout, or until it comes to rest)."""
        return float(self.peak_share * np.sqrt((self.span[1] - self.span[0]) / max(n_frames, 1)))

    def where(self, w: int, h: int) -> str:
        """Where the part lies in a ``w x h`` frame, in words (``"at the right edge"``, ``"in the centre"``)."""
        cx, cy = (self.box[0] + self.box[2]) / 2 / w, (self.box[1] + self.box[3]) / 2 / h
        side = "left" if cx < 0.33 else "right" if cx > 0.67 else ""
        level = "top" if cy < 0.33 else "bottom" if cy > 0.67 else ""
        name = "-".join(s for s in (level, side) if s)
        if not name:
            return "in the centre"
        return f"at the {name} edge" if self.touches_border else f"at the {name}"

    def describe(self) -> str:
        """How it moves, in words: its frequency, periods and peak share."""
        if not np.isfinite(self.frequency_hz):
            return "no periodic motion"
        return f"{self.frequency_hz:.2f} Hz over {self.periods:.1f} periods, its spectral peak {100 * self.peak_share:.0f}% of its motion"


def _centroids(x: np.ndarray, core: np.ndarray, span: tuple[int, int]) -> np.ndarray:
    """``[T, 2]`` centroid ``(x, y)`` of the departure of ``x [T, h, w]`` from the part's static scene, over ``core``.

    The static scene is the median over the frames where the part moves (``span``): an object that comes to
    rest would otherwise sit in the whole clip's median and leave a ghost at its rest position in every
    moving frame. Frames with no departure hold the last centroid.
    """
    ys, xs = np.nonzero(core)
    v = x[:, ys, xs]  # [T, n]
    d = np.abs(v - np.median(v[span[0] : span[1]], axis=0))
    m = d.sum(1)
    xy = np.stack([(d * xs).sum(1), (d * ys).sum(1)], 1) / np.maximum(m, 1e-12)[:, None]
    ok = m > 1e-3 * max(float(np.median(m)), 1e-12)
    if not ok.any():
        return np.zeros((len(m), 2))
    idx = np.where(ok, np.arange(len(m)), 0)
    np.maximum.accumulate(idx, out=idx)
    first = int(np.argmax(ok))
    idx[:first] = first
    return xy[idx]


def _activity(x: np.ndarray, pix: tuple[np.ndarray, np.ndarray], floor: float, bins: int) -> tuple[np.ndarray, np.ndarray]:
    """When each pixel changes: a frame-to-frame change over a third of the pixel's own largest, over
    :data:`EVENT_NOISE` times the noise level and over :data:`EVENT_MIN` (compression hides the noise of a still
    scene, then lets it through where something changes: the noise alone makes no event).

    Returns:
        ``(profile [n, bins], runs [n])``: the share of each time bin with a change, and the number of separate
        runs of changes (changes 3 frames apart or less join): an object passing over a pixel makes two (its
        front and its back), an oscillation two per visit.
    """
    a = np.abs(np.diff(x[:, pix[0], pix[1]], axis=0))  # [T-1, n]
    d = a > np.maximum(a.max(0) / 3.0, max(EVENT_NOISE * floor, EVENT_MIN))
    edges = np.linspace(0, d.shape[0], bins + 1).astype(int)
    prof = np.stack([d[a:b].mean(0) if b > a else np.zeros(d.shape[1]) for a, b in zip(edges[:-1], edges[1:])], 1)
    joined = maximum_filter1d(d.astype(np.uint8), 3, axis=0) > 0
    runs = joined[0].astype(int) + (joined[1:] & ~joined[:-1]).sum(0)
    return prof, runs


def _split_by_time(x: np.ndarray, core: np.ndarray, floor: float) -> list[np.ndarray]:
    """Split one spatial part into what moves throughout and what moves only briefly (a passer-by crossing the
    object's track moves only while passing; the object moves throughout, or until it comes to rest).

    A core pixel is *brief* when :data:`BRIEF_SHARE` of its activity (:func:`_activity`) over :data:`TIME_BINS`
    time bins falls in :data:`BRIEF_BINS` consecutive bins and something passed over it once (two runs of
    changes at most: the ends of a decaying swing are visited briefly too, but more than once); a pixel with no activity (a faint change that the
    noise hides) goes with the nearest pixel that has some. The brief pixels are split off when they and the
    others each make at least a tenth of the core. Returns the core masks (one, or two).
    """
    pix = np.nonzero(core)
    if pix[0].size < 20:
        return [core]
    prof, runs = _activity(x, pix, floor, TIME_BINS)
    total = prof.sum(1)
    if not (total > 0).any():
        return [core]
    prof = prof / np.maximum(total[:, None], 1e-12)  # when each pixel changes, not how often
    window = np.stack([prof[:, i : i + BRIEF_BINS].sum(1) for i in range(TIME_BINS - BRIEF_BINS + 1)], 1).max(1)
    group = np.full(core.shape, -1, np.int8)
    group[pix] = np.where(total > 0, ((window >= BRIEF_SHARE) & (runs <= 2)).astype(np.int8), -1)
    _, (iy, ix) = distance_transform_edt(group < 0, return_indices=True)
    near = group[iy, ix]  # every pixel's group, or its nearest active pixel's
    brief = near[pix] == 1
    if min(brief.sum(), (~brief).sum()) < 0.1 * brief.size:
        return [core]
    out = []
    for sel in (~brief, brief):
        m = np.zeros_like(core)
        m[pix[0][sel], pix[1][sel]] = True
        out.append(m)
    return out


def _main_blobs(core: np.ndarray, std: np.ndarray) -> np.ndarray:
    """``core`` without its stray blobs: the connected blobs (1 px apart) whose summed standard deviation is below
    :data:`BLOB_SHARE` of the largest's (the fringe that a split leaves along a passer-by's outline)."""
    lab, n = label(binary_dilation(core, iterations=1), structure=np.ones((3, 3)))
    if n <= 1:
        return core
    mass = np.bincount(lab[core], weights=std[core], minlength=n + 1)
    keep = mass >= BLOB_SHARE * mass.max()
    keep[0] = False
    return core & keep[lab]


def find_parts(x: np.ndarray, std: np.ndarray, floor: float, dt: float) -> list[Part]:
    """The clip's moving parts, strongest first (module docstring).

    Args:
        x: ``[T, h, w]`` grey frames in [0, 1].
        std: ``[h, w]`` temporal standard deviation (smoothed).
        floor: the sensor-noise level (same unit).
        dt: frame interval, s.

    Returns:
        Up to :data:`MAX_PARTS` parts, by decreasing mass; empty when nothing stands out.
    """
    T, h, w = x.shape
    top = float(std.max())
    # the still scene's own temporal spread (sensor noise that compression lets through, flicker): the median pixel's
    still = float(np.median(std))
    cand = binary_opening(std > max(PART_FRACTION * top, 4.0 * floor, STILL_FACTOR * still), iterations=1)
    # fragments of one object's sweep (a fast object leaves pixels it passes in few frames below the threshold)
    # join across gaps of up to twice JOIN_RADIUS of the frame's long side; then what moves at other times is split off
    reach = max(2, int(round(JOIN_RADIUS * max(h, w))))
    labels, n = label(binary_dilation(cand, iterations=reach), structure=np.ones((3, 3)))
    near = binary_dilation(cand, iterations=2)
    cores, regions, members = [], [], []
    for k in range(1, n + 1):
        comp = (labels == k) & near
        split = [_main_blobs(c, std) for c in _split_by_time(x, (labels == k) & cand, floor)]
        if len(split) == 2:  # each side a part, and the whole as a candidate too (a decaying swing's ends move briefly)
            owner = np.full((h, w), -1, np.int8)
            for j, c in enumerate(split):
                owner[c] = j
            _, (iy, ix) = distance_transform_edt(owner < 0, return_indices=True)
            first = len(cores)
            for j, c in enumerate(split):
                cores.append(c)
                regions.append(comp & (owner[iy, ix] == j))  # its pixels go to the nearer side
                members.append(())
            split, members_whole = [split[0] | split[1]], (first, first + 1)
        else:
            members_whole = ()
        cores.append(split[0])
        regions.append(comp)
        members.append(members_whole)
    if not cores:
        return []
    mass = np.array([float(std[c].sum()) for c in cores])
    order = [int(i) for i in np.argsort(-mass) if mass[i] >= MIN_PART_SHARE * mass.max()][:MAX_PARTS]
    change = np.zeros(T)
    parts = []
    for i in order:
        core, region = cores[i], regions[i]
        ys, xs = np.nonzero(region)
        change[1:] = np.abs(np.diff(x[:, core], axis=0)).mean(1)
        a, b = moving_span(change)
        xy = _centroids(x, core, (a, b))
        p, d = principal_path(xy[a:b])
        f, share = path_frequency(p, dt)
        periods = periods_held(p, f, dt)
        touches = bool(xs.min() <= 1 or ys.min() <= 1 or xs.max() >= w - 2 or ys.max() >= h - 2)
        box = (int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1)
        parts.append(Part(i + 1, region, box, float(mass[i]), xy, (a, b), p, d, f, share, periods, touches, tuple(m + 1 for m in members[i])))
    return parts


def _moves_with(obj: Part, other: Part) -> float:
    """Largest absolute correlation of ``other``'s centroid coordinates with ``obj``'s path, over ``obj``'s span."""
    a, b = obj.span
    best = 0.0
    for c in (other.xy[a:b, 0], other.xy[a:b, 1]):
        if np.std(c) > 1e-9 and np.std(obj.path) > 1e-9:
            best = max(best, abs(float(np.corrcoef(obj.path, c)[0, 1])))
    return best


def _apart(whole: Part, by_label: dict[int, Part]) -> bool:
    """Whether ``whole`` joins two oscillating sides that move independently (a pendulum and the hand beside
    it that let it go): each side oscillates on its own (:attr:`Part.oscillates`) and neither's path follows
    the other's (:func:`_moves_with` below :data:`MOVES_WITH` both ways), so the whole is two things, not one
    seen two ways, and it is no candidate for the object. The ends of one decaying swing, split off because
    they are visited briefly, follow the swing's path; a side with no oscillation of its own (the object's
    fringe, the place where it rests) leaves the whole a candidate."""
    sides = [by_label.get(k) for k in whole.members]
    if len(sides) != 2 or any(s is None or not s.oscillates for s in sides):
        return False
    a, b = sides
    return max(_moves_with(a, b), _moves_with(b, a)) < MOVES_WITH


def choose_object(parts: list[Part]) -> tuple[list[Part], list[Part], str | None]:
    """Split the parts into the object (first, with the parts that move with it) and the dropped ones.

    The object is the oscillating part (:attr:`Part.oscillates`) with the clearest peak; parts within
    5 points of its peak share are ranked by mass. A part split by time whose two sides move independently
    (:func:`_apart`) is no candidate as a whole; its sides are. When no part oscillates, the strongest part is the
    object, and the third value says so. Every part gets its :attr:`Part.verdict`.

    Returns:
        ``(kept, dropped, note)``: ``kept[0]`` is the object; ``note`` is ``None`` or a sentence for the log.

    Raises:
        ValueError: if ``parts`` is empty.
    """
    if not parts:
        raise ValueError("no moving parts to choose from")
    note = None
    T = len(parts[0].xy)
    by_label = {p.label: p for p in parts}
    osc = [p for p in parts if p.oscillates and not _apart(p, by_label)]
    if osc:
        best = max(p.score(T) for p in osc)
        obj = max((p for p in osc if p.score(T) >= best - 0.05), key=lambda p: p.mass)
    else:
        obj = parts[0]
        note = f"no moving part shows a clear oscillation; the strongest taken as the object ({obj.describe()})"
    obj.verdict = "object"
    # a split part and its whole are one thing seen two ways: the chosen one stands for both
    inside = set(obj.members)
    hidden = {p.label for p in parts if p.members and obj.label in p.members} | inside
    kept, dropped = [obj], []
    for p in parts:
        if p is obj or p.label in hidden:
            if p.label in inside:
                p.verdict = "part of the object"
            continue
        r = _moves_with(obj, p)
        if r >= MOVES_WITH:
            p.verdict = f"moves with the object (correlation {r:.2f})"
            kept.append(p)
        elif p.oscillates:
            p.verdict = f"oscillates on its own, less clearly ({p.describe()})"
            dropped.append(p)
        else:
            p.verdict = f"no clear oscillation ({p.describe()})"
            dropped.append(p)
    for p in list(dropped):  # a whole whose sides were judged already
        if p.members and any(q.label in p.members for q in kept + dropped if q is not p):
            dropped.remove(p)
    return kept, dropped, note
