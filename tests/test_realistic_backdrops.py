"""The backdrop clips (lagsplat.synth.realistic.backdrops): the suite's oscillators on other walls, with other
distractors and at other sizes. Rendering is skipped without MuJoCo or an offscreen GL context (EGL)."""

from __future__ import annotations

import json

import numpy as np
import pytest

import lagsplat.synth.realistic.camera  # noqa: F401  (sets MUJOCO_GL=egl before MuJoCo is imported)
from lagsplat.synth.realistic import SIZES, backdrop_clips, clip_spec, motion_of, nuisance_clips, outside_class_clips, realistic_suite
from lagsplat.synth.realistic.backdrops import PHOTOS, backdrop_scene, wood_texture

SUITE_KEYS = {"t", "q", "qdot", "hidden", "f0_hz", "truth_json"}




def test_the_list_is_well_formed_and_apart_from_the_suite_and_the_nuisance_clips() -> None:
    entries = backdrop_clips()
    names = [e["name"] for e in entries]
    others = {e["name"] for e in realistic_suite() + outside_class_clips() + nuisance_clips()}
    assert 10 <= len(names) == len(set(names)) and not others & set(names)
    assert all(clip_spec(n) == e for n, e in zip(names, entries))  # resolvable like the suite's clips
    assert {e["system"] for e in entries} == {"pendulum", "spring_cart", "torsion_disk"}
    assert {e["backdrop"] for e in entries} == {"checker", "wood", "clutter", *PHOTOS}
    assert 2 <= sum(e["effect"] != "none" for e in entries) <= 3
    assert 2 <= sum(e["mover"] is not None for e in entries) <= 3 and sum(e["moving_light"] for e in entries) == 2
    assert min(e["scale"] for e in entries) <= 0.5 and max(e["scale"] for e in entries) >= 1.5
    assert {e["size"] for e in entries} - {"128"} and all(e["size"] in SIZES for e in entries)
    suite = {e["name"] for e in realistic_suite()}
    assert all(e["twin"] in suite and e["name"].startswith(e["system"] + "-bd_") for e in entries)


def test_the_motion_is_the_suite_twins_and_the_movers_miss_its_frequency() -> None:
    for e in backdrop_clips():
        m = motion_of(e, 30.0, 12.0)
        twin = motion_of(clip_spec(e["twin"]), 30.0, 12.0)
        assert np.array_equal(m.q, twin.q) and m.f0_hz == twin.f0_hz
        k = int(e["mover"] is not None) + int(e["moving_light"])
        assert (m.extras["backdrop_qpos"].shape == (len(m.t), k)) if k else "backdrop_qpos" not in m.extras
        for f in m.truth.get("mover_hz", []):  # neither the mover nor its first harmonics at the object's frequency
            assert all(abs(h * f - m.f0_hz) > 0.15 * m.f0_hz for h in (1, 2, 3)), (e["name"], f, m.f0_hz)


def test_the_scene_takes_out_the_suites_distractors_and_scales_the_object() -> None:
    e = next(e for e in backdrop_clips() if e["system"] == "torsion_disk" and e["scale"] != 1.0)
    xml = backdrop_scene(e)
    assert 'name="crate"' not in xml and 'name="bottle"' not in xml and 'material="bd"' in xml
    r = 0.2 * e["scale"]
    assert f'size="{r:g} ' in xml
    assert backdrop_scene(e) == xml  # seeded
    w = wood_texture(0)
    assert w.shape == (512, 512, 3) and w.dtype == np.uint8 and np.array_equal(w, wood_texture(0)) and w.std() > 10


def _first_frame(name: str, tmp, **kw) -> np.ndarray:
    import cv2

    from lagsplat.synth.realistic import make_clip

    cap = cv2.VideoCapture(str(make_clip(name, tmp, **kw)))
    ok, f = cap.read()
    cap.release()
    assert ok
    return f.astype(np.float32).mean(-1)


def test_a_checker_clip_renders_deterministically_with_its_truth(gl_ok, tmp_path) -> None:
    name = "pendulum-bd_checker-s0-128"
    a = tmp_path / "a"
    fa = _first_frame(name, a, duration_s=0.6)
    fb = _first_frame(name, tmp_path / "b", duration_s=0.6)
    assert fa.shape == (128, 128) and np.array_equal(fa, fb)
    assert (a / f"{name}.mp4").read_bytes() == (tmp_path / "b" / f"{name}.mp4").read_bytes()
    suite = _first_frame(clip_spec(name)["twin"], tmp_path / "s", duration_s=0.6)
    # static-pixel contrast: neighbouring pixels of the black and white squares differ far more than on the suite's wall
    def contrast(f: np.ndarray) -> float:
        return float(np.abs(np.diff(f[16:-16, 16:-16], axis=1)).mean())

    assert contrast(fa) > 2.5 * contrast(suite), (contrast(fa), contrast(suite))
    z = np.load(a / f"{name}.truth.npz")
    assert SUITE_KEYS <= set(z.files) and z["q"].shape == (18, 1) and float(z["f0_hz"]) > 0
    truth = json.loads(str(z["truth_json"]))
    assert truth["backdrop"] == "checker" and truth["width"] == 128 and truth["f0_hz"] == pytest.approx(float(z["f0_hz"]))


@pytest.mark.slow
def test_every_backdrop_and_mover_renders_at_its_size(gl_ok, tmp_path) -> None:
    for e in backdrop_clips():
        f = _first_frame(e["name"], tmp_path, duration_s=0.6)
        W, H = SIZES[e["size"]]
        assert f.shape == (H, W) and f.std() > 15, e["name"]
        z = np.load(tmp_path / f"{e['name']}.truth.npz")
        assert SUITE_KEYS <= set(z.files)
