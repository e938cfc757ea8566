"""Which moving part is the object when one part was split by time into two sides (lagsplat.prepare.parts)."""

from __future__ import annotations

import numpy as np

from lagsplat.prepare.frequency import path_frequency, periods_held
from lagsplat.prepare.parts import Part, choose_object

DT, T = 1.0 / 30.0, 120  # 4 s


def _part(label: int, path: np.ndarray, mass: float, members: tuple[int, ...] = (), x0: int = 0) -> Part:
    """A part whose centroid runs along ``path`` (px, horizontally) over the whole clip, its frequency read as
    preparation reads it."""
    f, share = path_frequency(path, DT)
    periods = periods_held(path, f, DT)
    xy = np.stack([x0 + path, np.full(T, 50.0)], 1)
    region = np.zeros((120, 160), bool)
    region[40:60, x0 : x0 + 40] = True
    return Part(label, region, (x0, 40, x0 + 40, 60), mass, xy, (0, T), path, np.array([1.0, 0.0]), f, share, periods, False, members)


def test_a_hand_split_off_a_pendulum_is_set_aside_and_the_pendulum_is_the_object() -> None:
    """A small bob swinging at 0.575 Hz and a heavier hand moving on its own at about 0.45 Hz, joined in space and
    split by time: the whole, dominated by the hand, shows the clearer peak, but its sides move independently,
    so the whole is two things and the bob is chosen."""
    t = np.arange(T) * DT
    rng = np.random.default_rng(1)
    bob = 20 * np.cos(2 * np.pi * 0.575 * t) + rng.normal(0, 5, T)
    hand = 5 * np.sin(2 * np.pi * 0.45 * t + 1.0) + np.cumsum(rng.normal(0, 2.5, T))
    whole_path = 15 * np.sin(2 * np.pi * 0.45 * t + 1.0) + np.cumsum(rng.normal(0, 1.0, T))  # the hand's rhythm, clearer
    side_bob, side_hand = _part(1, bob, 26.0), _part(2, hand, 140.0, x0=80)
    whole = _part(3, whole_path, 166.0, members=(1, 2))
    assert side_bob.oscillates and side_hand.oscillates and whole.peak_share > side_bob.peak_share + 0.1
    kept, dropped, note = choose_object([whole, side_hand, side_bob])
    assert kept[0] is side_bob and note is None
    assert side_hand in dropped and side_hand.verdict.startswith("oscillates on its own")
    assert abs(kept[0].frequency_hz / 0.575 - 1) < 0.05


def test_a_whole_whose_sides_move_together_or_whose_side_is_still_stays_a_candidate() -> None:
    """The two ends of one swing (both follow its path), or a swing and a fringe with no oscillation of its own
    (where the object rests): the whole is one object seen two ways, and chosen for its clearer peak."""
    t = np.arange(T) * DT
    swing = 20 * np.cos(2 * np.pi * 0.6 * t)
    rng = np.random.default_rng(1)
    for other in (0.7 * swing + rng.normal(0, 2.0, T), rng.normal(0, 1.0, T)):
        a, b = _part(1, swing + rng.normal(0, 6.0, T), 60.0), _part(2, other, 20.0, x0=60)
        whole = _part(3, swing, 80.0, members=(1, 2))
        kept, _, _ = choose_object([whole, a, b])
        assert kept[0] is whole
