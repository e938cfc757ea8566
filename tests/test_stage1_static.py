"""Stage 1 with the static-motion prior (stage1.w_static; lagsplat.train.losses.static_motion_penalty).

Trains the real Stage-1 loop twice on a small synthetic pendulum clip, with and
without the prior, and measures what a force would move on the pixels that
never change: the composited motion field ``sum_i T_i a_i J_i std(z)`` there
(the quantity the visible brush of ``lagsplat.forces.transport`` pulls back, paper Eq. 9).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lagsplat.synth.pendulum import make_pendulum_clip
from lagsplat.train.losses import static_motion_penalty
from lagsplat.train.stage1 import Stage1Config, static_pixels, train_stage1
from lagsplat.models.autoencoder import frames_to_tensor


def _static_motion_and_mse(ae, clip, static: torch.Tensor) -> tuple[float, float]:
    X = frames_to_tensor(clip.images[clip.train_idx])
    with torch.no_grad():
        z = ae.encode(X)
        img, motion = ae.decoder.render_motion(z, ae.height, ae.width, z.std(0))
    rms_static = float(static_motion_penalty(motion, static).sqrt())
    return rms_static, float((img - X).pow(2).mean())


@pytest.mark.slow
def test_static_prior_stills_the_background_and_keeps_the_reconstruction() -> None:
    clip = make_pendulum_clip(size=(32, 32), duration_s=6.0, seed=0)
    static = static_pixels(clip.images[clip.train_idx], margin=1.0)
    assert static is not None and 50 < int(static.sum()) < 32 * 32 - 50  # both static and changing pixels
    base = dict(n_gaussians=256, steps=250, recycle_warmup=100, recycle_every=50, threads=1, sigma_xy=0.05)
    ae0, _ = train_stage1(clip, Stage1Config(**base), d=1, seed=0, progress=False)
    ae1, _ = train_stage1(clip, Stage1Config(**base, w_static=1e-2), d=1, seed=0, progress=False)
    m0, mse0 = _static_motion_and_mse(ae0, clip, static)
    m1, mse1 = _static_motion_and_mse(ae1, clip, static)
    assert m1 < 0.25 * m0, (m0, m1)  # px of motion a push on static pixels would meet
    assert mse1 < 1.5 * mse0, (mse0, mse1)  # the reconstruction is not traded away


def test_static_pixels_exclude_what_changes_and_its_margin() -> None:
    T, H, W = 12, 10, 16
    imgs = np.full((T, H, W, 3), 90, np.uint8)
    imgs[:, 4:6, 7:9] = (np.arange(T) * 20)[:, None, None, None]
    st = static_pixels(imgs, margin=1.0)
    assert not bool(st[4:6, 7:9].any()) and bool(st[0, 0]) and bool(st[9, 15])
    wide = static_pixels(imgs, margin=4.0)
    assert int(wide.sum()) < int(st.sum()) and not bool(wide[5, 11])
    assert static_pixels(np.full((T, H, W, 3), 90, np.uint8)) is None  # nothing moves: no prior
