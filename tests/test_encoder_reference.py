"""The encoder's reference image (stage1.encoder_reference): the encoder reads each frame's departure from the
static scene, and the reference travels with the checkpoint."""

from __future__ import annotations

import numpy as np
import torch

from lagsplat.models.autoencoder import frames_to_tensor, load_stage1, save_stage1
from lagsplat.models.encoder import CpAEEncoder
from lagsplat.synth.pendulum import make_pendulum_clip
from lagsplat.train.stage1 import Stage1Config, train_stage1


def test_an_encoder_with_a_reference_encodes_the_departure_from_it() -> None:
    torch.manual_seed(0)
    plain = CpAEEncoder(2, (2, 2, 2), 5)
    ref_enc = CpAEEncoder(2, (2, 2, 2), 5)
    ref_enc.load_state_dict(plain.state_dict())
    reference = torch.rand(3, 24, 32)
    ref_enc.set_reference(reference)
    x = torch.rand(4, 3, 24, 32)
    with torch.no_grad():
        assert torch.allclose(ref_enc(x), plain(x - reference), atol=1e-6)
        assert torch.allclose(ref_enc(reference[None]), plain(torch.zeros(1, 3, 24, 32)), atol=1e-6)  # the scene itself: no departure
        assert not torch.allclose(ref_enc(x), plain(x), atol=1e-4)
    ref_enc.set_reference(None)
    assert ref_enc.reference is None and "reference" not in ref_enc.state_dict()


def test_training_with_the_reference_keeps_the_median_frame_and_the_checkpoint_carries_it(tmp_path) -> None:
    clip = make_pendulum_clip(size=(16, 16), duration_s=2.0, seed=0)
    X = frames_to_tensor(clip.images[clip.train_idx])
    cfg = Stage1Config(n_gaussians=16, steps=3, threads=1, encoder_reference=True)
    ae, hist = train_stage1(clip, cfg, d=1, seed=0, progress=False)
    assert torch.equal(ae.encoder.reference, X.median(0).values)
    save_stage1(tmp_path / "stage1.pt", ae, {"backend": "auto"}, hist, 1)
    back = load_stage1(tmp_path / "stage1.pt")
    assert torch.equal(back.encoder.reference, ae.encoder.reference)
    with torch.no_grad():
        assert torch.equal(back.encode(X), ae.encoder(X))
    # a checkpoint of the paper's encoder (no reference) loads as before
    plain, _ = train_stage1(clip, Stage1Config(n_gaussians=16, steps=3, threads=1), d=1, seed=0, progress=False)
    assert plain.encoder.reference is None
    save_stage1(tmp_path / "plain.pt", plain, {"backend": "auto"}, {}, 1)
    assert load_stage1(tmp_path / "plain.pt").encoder.reference is None
    with torch.no_grad():
        assert np.isfinite(back.encode(X).numpy()).all()
