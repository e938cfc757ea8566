"""Tests of the 2D Gaussian rasterisers (lagsplat.render).

The compositing rule stated in the docstring of :mod:`lagsplat.render.rasterize`
is the specification: ``rasterize_dense`` is checked against it by hand, then
the two culled backends (``rasterize_tiles``, pure torch, and ``rasterize_cpu``,
numba kernels) are checked against ``rasterize_dense`` pixel by pixel and
gradient by gradient.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lagsplat.render import cpu_kernels as ck
from lagsplat.render import rasterize as R
from lagsplat.render.rasterize import rasterize, rasterize_dense, rasterize_tiles
from lagsplat.render.rasterize_cpu import rasterize_cpu
from lagsplat.render.rasterize_gsplat import gsplat_available, rasterize_gsplat
from lagsplat.render.rule import ALPHA_MAX, ALPHA_MIN, EPS2D, pixel_bounds, prepare_gaussians

CULLED = {"tiles": rasterize_tiles, "cpu": rasterize_cpu}


def _culled(name: str, tile: int) -> dict:
    """Keyword arguments for a culled backend: the torch one takes the tile edge, the compiled one has its own."""
    return {"tile": tile} if name == "tiles" else {}


# ----------------------------------------------------------------------------- scenes
def _rotated_covs(std: torch.Tensor, theta: torch.Tensor) -> torch.Tensor:
    """Covariances ``R diag(std^2) R^T`` from ``[...,2]`` standard deviations and angles."""
    c, s = torch.cos(theta), torch.sin(theta)
    rot = torch.stack([torch.stack([c, -s], -1), torch.stack([s, c], -1)], -2)
    return rot @ torch.diag_embed(std**2) @ rot.transpose(-1, -2)


def _scene(
    B: int,
    K: int,
    H: int,
    W: int,
    seed: int,
    cov_batched: bool = False,
    col_batched: bool = False,
    dtype: torch.dtype = torch.float32,
):
    """A hard random scene: sizes from sub-pixel to 20 px, anisotropy, primitives
    partly and fully off-screen, opacities near 0, near 1 and above the cap."""
    g = torch.Generator().manual_seed(seed)
    lo = torch.tensor([-0.3 * W, -0.3 * H])
    span = torch.tensor([1.6 * W, 1.6 * H])
    means = lo + span * torch.rand(B, K, 2, generator=g)
    means[:, 0] = torch.tensor([-200.0, 0.5 * H])  # fully off-screen (left), even at 20 px std
    means[:, 1] = torch.tensor([W + 200.0, H + 200.0])  # fully off-screen (bottom right)
    cshape = (B, K) if cov_batched else (K,)
    std = torch.exp(torch.empty(*cshape, 2).uniform_(math.log(0.05), math.log(20.0), generator=g))
    theta = torch.rand(*cshape, generator=g) * math.pi
    covs = _rotated_covs(std, theta)
    # opacity classes: below the 1/255 cut, just above it, mid, near 1, above the 0.99 cap
    classes = torch.tensor([0.001, 0.0045, 0.5, 0.985, 1.3])
    pick = torch.randint(0, len(classes), (B, K), generator=g)
    opac = classes[pick] * (1.0 + 0.02 * torch.rand(B, K, generator=g))
    opac = torch.where(pick == 2, torch.rand(B, K, generator=g), opac)
    colors = torch.rand(*((B, K, 3) if col_batched else (K, 3)), generator=g)
    return means.to(dtype), covs.to(dtype), opac.to(dtype), colors.to(dtype)


def _smooth_scene(B: int, K: int, H: int, W: int, seed: int, dtype: torch.dtype):
    """A scene on which the renderer is smooth: every pixel is well inside every
    support ellipse (d2 < 1) and every alpha is in [0.25, 0.65], far from the
    1/255 cut and from the 0.99 cap."""
    g = torch.Generator().manual_seed(seed)
    centre = torch.tensor([W / 2.0, H / 2.0])
    means = centre + (torch.rand(B, K, 2, generator=g) - 0.5) * 2.0
    std = 8.0 + 4.0 * torch.rand(B, K, 2, generator=g)
    covs = _rotated_covs(std, torch.rand(B, K, generator=g) * math.pi)
    opac = 0.4 + 0.25 * torch.rand(B, K, generator=g)
    colors = torch.rand(B, K, 3, generator=g)
    bg = torch.tensor([0.3, 0.6, 0.1])
    return tuple(t.to(dtype) for t in (means, covs, opac, colors, bg))


# ----------------------------------------------------------------------------- forward equality
_VARIANTS = [
    # (background, [B,K,2,2] covariances, [B,K,3] colours)
    (False, False, False),
    (True, True, False),
    (True, False, True),
    (False, True, True),
]


@pytest.mark.parametrize("HW", [(37, 51), (16, 16), (5, 64)])
@pytest.mark.parametrize("tile", [4, 8, 16])
@pytest.mark.parametrize("B", [1, 3])
@pytest.mark.parametrize("variant", range(len(_VARIANTS)))
def test_culled_backends_equal_dense(HW, tile, B, variant) -> None:
    H, W = HW
    use_bg, cov_b, col_b = _VARIANTS[variant]
    K = 48
    seed = 1000 * H + 10 * W + tile + B + 7 * variant
    means, covs, opac, colors = _scene(B, K, H, W, seed, cov_batched=cov_b, col_batched=col_b)
    bg = torch.tensor([0.2, 0.55, 0.9]) if use_bg else None
    ref = rasterize_dense(means, covs, opac, colors, H, W, bg)
    assert ref.shape == (B, 3, H, W)
    # the scene is not trivial: something is drawn, and the 0.99 cap is reached somewhere
    drawn = ref if bg is None else ref - bg.view(1, 3, 1, 1)
    assert drawn.abs().max() > 0.1
    for name, fn in CULLED.items():
        out = fn(means, covs, opac, colors, H, W, bg, **_culled(name, tile))
        assert out.shape == ref.shape and out.dtype == ref.dtype, name
        torch.testing.assert_close(out, ref, atol=1e-5, rtol=0, msg=lambda m: f"{name}: {m}")
    # rasterize_cpu has two paths: the autograd kernels (inputs need gradients)
    # and the inference kernel (no gradients); they must agree bit for bit
    with torch.no_grad():
        infer = rasterize_cpu(means, covs, opac, colors, H, W, bg)
    train = rasterize_cpu(means.clone().requires_grad_(), covs, opac, colors, H, W, bg)
    assert train.requires_grad and not infer.requires_grad
    assert torch.equal(train.detach(), infer)


def test_dispatcher_routes_to_the_same_image() -> None:
    H, W = 21, 30
    means, covs, opac, colors = _scene(2, 30, H, W, seed=3)
    bg = torch.tensor([0.1, 0.2, 0.3])
    ref = rasterize_dense(means, covs, opac, colors, H, W, bg)
    for backend in ("auto", "cpu", "torch", "dense"):
        out = rasterize(means, covs, opac, colors, H, W, bg, backend=backend)
        torch.testing.assert_close(out, ref, atol=1e-5, rtol=0)


def test_cap_and_cut_are_exercised_by_the_scenes() -> None:
    # Guard for the equality test above: its scenes do contain capped alphas
    # (o exp(-d2/2) > 0.99), cut alphas (below 1/255 or outside 3 sigma) and
    # primitives that draw nothing at all.
    H, W = 37, 51
    means, covs, opac, colors = _scene(3, 48, H, W, seed=11, cov_batched=True)
    ones = torch.ones(3, 48, 1)
    per_prim = torch.stack(
        [rasterize_dense(means[:, k : k + 1], covs[:, k : k + 1], opac[:, k : k + 1], ones[:, k : k + 1], H, W)[:, 0] for k in range(48)],
        1,
    )  # [B,K,H,W] = alpha of each primitive alone
    assert torch.isclose(per_prim.max(), torch.tensor(ALPHA_MAX))
    assert ((per_prim > 0) & (per_prim < 2 * ALPHA_MIN)).any()
    assert (per_prim.flatten(2).amax(-1) == 0).sum() >= 6  # off-screen and sub-threshold ones


# ----------------------------------------------------------------------------- gradients
def _grads(fn, means, covs, opac, colors, H, W, bg, upstream, **kw):
    leaves = [t.detach().clone().requires_grad_(True) for t in (means, covs, opac, colors)]
    img = fn(*leaves, H, W, bg, **kw)
    (img * upstream).sum().backward()
    return [t.grad for t in leaves]


def _assert_rel(a: torch.Tensor, b: torch.Tensor, rtol: float, what: str) -> None:
    scale = b.abs().max().clamp_min(1e-12)
    err = (a - b).abs().max()
    assert err <= rtol * scale, f"{what}: max abs err {err:.3e} vs scale {scale:.3e}"


@pytest.mark.parametrize(
    "H,W,tile,B,cov_b,col_b",
    [
        (37, 51, 8, 1, False, False),
        (37, 51, 4, 3, True, True),
        (5, 64, 16, 3, False, True),
        (16, 16, 16, 2, True, False),
    ],
)
def test_culled_gradients_equal_dense(H, W, tile, B, cov_b, col_b) -> None:
    means, covs, opac, colors = _scene(B, 40, H, W, seed=H + W + tile + B, cov_batched=cov_b, col_batched=col_b)
    bg = torch.tensor([0.3, 0.1, 0.7])
    up = torch.randn(B, 3, H, W, generator=torch.Generator().manual_seed(5))
    ref = _grads(rasterize_dense, means, covs, opac, colors, H, W, bg, up)
    names = ("means", "covs", "opacities", "colors")
    for r, n in zip(ref, names):
        assert r.abs().max() > 0, n  # every input does receive a gradient
    for bname, fn in CULLED.items():
        got = _grads(fn, means, covs, opac, colors, H, W, bg, up, **_culled(bname, tile))
        for g, r, n in zip(got, ref, names):
            assert g.shape == r.shape
            _assert_rel(g, r, 1e-4, f"{bname} d/d{n}")


def test_tiles_gradients_equal_dense_in_double() -> None:
    H, W = 23, 29
    means, covs, opac, colors = _scene(2, 40, H, W, seed=77, cov_batched=True, dtype=torch.float64)
    bg = torch.tensor([0.3, 0.1, 0.7], dtype=torch.float64, requires_grad=True)
    up = torch.randn(2, 3, H, W, dtype=torch.float64, generator=torch.Generator().manual_seed(6))
    ref = _grads(rasterize_dense, means, covs, opac, colors, H, W, bg, up)
    bg_ref = bg.grad.clone()
    bg.grad = None
    got = _grads(rasterize_tiles, means, covs, opac, colors, H, W, bg, up, tile=8)
    for g, r in zip(got, ref):
        torch.testing.assert_close(g, r, rtol=1e-9, atol=1e-10)
    torch.testing.assert_close(bg.grad, bg_ref, rtol=1e-9, atol=1e-10)


def test_gradcheck_dense_and_tiles() -> None:
    H, W = 5, 6
    inputs = _smooth_scene(2, 3, H, W, seed=1, dtype=torch.float64)
    inputs = tuple(t.clone().requires_grad_(True) for t in inputs)
    means, covs, opac, colors, bg = inputs
    # the smoothness premise of the scene actually holds
    with torch.no_grad():
        per = rasterize_dense(means.reshape(6, 1, 2), covs.reshape(6, 1, 2, 2), opac.reshape(6, 1), torch.ones(6, 1, 1), H, W)
        assert per.min() > 0.2 and per.max() < 0.7

    def dense(m, c, o, col, b):
        return rasterize_dense(m, c, o, col, H, W, b)

    def tiles(m, c, o, col, b):
        return rasterize_tiles(m, c, o, col, H, W, b, tile=4)

    assert torch.autograd.gradcheck(dense, inputs, eps=1e-6, atol=1e-6)
    assert torch.autograd.gradcheck(tiles, inputs, eps=1e-6, atol=1e-6)
    # second order (the torch backend supports double backward), on a smaller case
    small = tuple(t.clone().requires_grad_(True) for t in _smooth_scene(1, 2, 3, 4, seed=5, dtype=torch.float64))

    def tiles_small(m, c, o, col, b):
        return rasterize_tiles(m, c, o, col, 3, 4, b, tile=2)

    assert torch.autograd.gradgradcheck(tiles_small, small, eps=1e-6, atol=1e-5)


def test_cpu_gradients_match_finite_differences() -> None:
    H, W = 7, 9
    means, covs, opac, colors, bg = _smooth_scene(2, 4, H, W, seed=2, dtype=torch.float32)
    up = torch.randn(2, 3, H, W, generator=torch.Generator().manual_seed(3))
    base = [means, covs, opac, colors]

    def loss(ts):
        return float((rasterize_cpu(*ts, H, W, bg).double() * up.double()).sum())

    grads = _grads(rasterize_cpu, *base, H, W, bg, up)
    gen = torch.Generator().manual_seed(4)
    eps = {0: 1e-2, 1: 5e-2, 2: 1e-3, 3: 1e-3}  # per-input step (pixels, pixels^2, -, -)
    for i in range(4):
        for _ in range(3):
            v = torch.randn(base[i].shape, generator=gen)
            if i == 1:
                v = 0.5 * (v + v.transpose(-1, -2))
            plus = [t.clone() for t in base]
            minus = [t.clone() for t in base]
            plus[i] = plus[i] + eps[i] * v
            minus[i] = minus[i] - eps[i] * v
            fd = (loss(plus) - loss(minus)) / (2 * eps[i])
            ad = float((grads[i] * v).sum())
            assert abs(fd - ad) <= 2e-2 * abs(ad) + 1e-3, (i, fd, ad)


# ----------------------------------------------------------------------------- first principles
def _d2_by_hand(px: float, py: float, mu, cov) -> float:
    sxx, sxy, syy = cov[0][0] + EPS2D, cov[0][1], cov[1][1] + EPS2D
    det = sxx * syy - sxy * sxy
    dx, dy = px - mu[0], py - mu[1]
    return (syy * dx * dx - 2 * sxy * dx * dy + sxx * dy * dy) / det


def _alpha_by_hand(px: float, py: float, mu, cov, o: float) -> float:
    d2 = _d2_by_hand(px, py, mu, cov)
    a = min(0.99, o * math.exp(-0.5 * d2))
    if d2 > 9.0 or a < 1.0 / 255.0:
        return 0.0
    return a


@pytest.mark.parametrize("o", [0.2, 0.8, 3.0])
def test_dense_single_gaussian_by_hand(o: float) -> None:
    H, W = 9, 11
    mu = (4.3, 3.7)
    cov = ((1.4, 0.5), (0.5, 0.9))
    col = (0.3, 0.6, 0.9)
    bg = (0.1, 0.2, 0.05)
    img = rasterize_dense(
        torch.tensor([[mu]], dtype=torch.float64),
        torch.tensor([cov], dtype=torch.float64),
        torch.tensor([[o]], dtype=torch.float64),
        torch.tensor([col], dtype=torch.float64),
        H,
        W,
        torch.tensor(bg, dtype=torch.float64),
    )[0]
    seen_cap = seen_alpha_cut = seen_support_cut = False
    for i in range(H):
        for j in range(W):
            a = _alpha_by_hand(j + 0.5, i + 0.5, mu, cov, o)
            d2 = _d2_by_hand(j + 0.5, i + 0.5, mu, cov)
            seen_cap |= a == 0.99
            seen_alpha_cut |= d2 < 9.0 and a == 0.0  # inside 3 sigma, below 1/255
            seen_support_cut |= d2 > 9.0 and o * math.exp(-0.5 * d2) >= 1.0 / 255.0  # visible but outside 3 sigma
            for c in range(3):
                expect = col[c] * a + (1.0 - a) * bg[c]
                assert img[c, i, j].item() == pytest.approx(expect, abs=1e-12), (i, j, c)
    # every branch of the rule is exercised: the 1/255 cut lies inside 3 sigma iff o < e^4.5 / 255
    o_switch = math.exp(4.5) / 255.0
    assert seen_cap == (o > 1.0)
    assert seen_alpha_cut == (o < o_switch)
    assert seen_support_cut == (o > o_switch)


def test_dense_over_compositing_follows_index_order() -> None:
    H, W = 8, 10
    mus = [(4.0, 3.5), (5.5, 4.5)]
    covs = [((3.0, 0.4), (0.4, 2.0)), ((2.0, -0.6), (-0.6, 3.5))]
    ops = [0.7, 0.6]
    cols = [(1.0, 0.2, 0.0), (0.0, 0.5, 1.0)]
    bg = torch.tensor([0.2, 0.2, 0.2], dtype=torch.float64)

    def render(order):
        t = lambda x: torch.tensor([x[k] for k in order], dtype=torch.float64)  # noqa: E731
        return rasterize_dense(t(mus)[None], t(covs), t(ops)[None], t(cols), H, W, bg)[0]

    ab, ba = render([0, 1]), render([1, 0])
    A = torch.zeros(H, W, dtype=torch.float64)
    Bm = torch.zeros(H, W, dtype=torch.float64)
    for i in range(H):
        for j in range(W):
            A[i, j] = _alpha_by_hand(j + 0.5, i + 0.5, mus[0], covs[0], ops[0])
            Bm[i, j] = _alpha_by_hand(j + 0.5, i + 0.5, mus[1], covs[1], ops[1])
    cA = torch.tensor(cols[0], dtype=torch.float64).view(3, 1, 1)
    cB = torch.tensor(cols[1], dtype=torch.float64).view(3, 1, 1)
    bgv = bg.view(3, 1, 1)
    # index 0 is in front: C = cA aA + cB aB (1 - aA) + bg (1 - aA)(1 - aB)
    torch.testing.assert_close(ab, cA * A + cB * Bm * (1 - A) + bgv * (1 - A) * (1 - Bm), rtol=0, atol=1e-12)
    torch.testing.assert_close(ba, cB * Bm + cA * A * (1 - Bm) + bgv * (1 - A) * (1 - Bm), rtol=0, atol=1e-12)
    # swapping changes the image by exactly aA aB (cA - cB), and that is not zero
    torch.testing.assert_close(ab - ba, A * Bm * (cA - cB), rtol=0, atol=1e-12)
    assert (ab - ba).abs().max() > 0.1
    # the culled backends keep the same order
    for order, ref in (([0, 1], ab), ([1, 0], ba)):
        t = lambda x: torch.tensor([x[k] for k in order], dtype=torch.float32)  # noqa: E731
        args = (t(mus)[None], t(covs), t(ops)[None], t(cols), H, W, bg.float())
        for name, fn in CULLED.items():
            torch.testing.assert_close(fn(*args, **_culled(name, 4))[0].double(), ref, rtol=0, atol=1e-6)


# ----------------------------------------------------------------------------- culling
def _pairs(means, covs, opac, H, W, tile):
    B, K = opac.shape
    _, _, _, _, r2, sxx, syy = prepare_gaussians(means, covs, opac, torch.ones(K, 1), EPS2D)
    x0, x1, y0, y1, valid = (v.reshape(-1).numpy() for v in pixel_bounds(means, r2, sxx, syy, H, W))
    ntx, nty = math.ceil(W / tile), math.ceil(H / tile)
    pairs, key_start = ck.bin_pairs(x0, x1, y0, y1, valid, K, ntx * nty, ntx, tile)
    return pairs, key_start, ntx, nty


def test_culling_is_real_and_never_drops_a_touched_tile() -> None:
    H, W, tile, K = 96, 128, 8, 200
    g = torch.Generator().manual_seed(9)
    means = torch.rand(1, K, 2, generator=g) * torch.tensor([W, H])
    means[0, 0] = torch.tensor([-30.0, 40.0])  # fully off-screen, left
    means[0, 1] = torch.tensor([60.0, H + 25.0])  # fully off-screen, below
    std = 0.5 + 1.0 * torch.rand(K, 2, generator=g)  # a few pixels each
    covs = _rotated_covs(std, torch.rand(K, generator=g) * math.pi)
    opac = 0.2 + 0.7 * torch.rand(1, K, generator=g)
    opac[0, 2] = 0.5 * ALPHA_MIN  # invisible everywhere
    pairs, key_start, ntx, nty = _pairs(means, covs, opac, H, W, tile)
    n_tiles = ntx * nty
    assert key_start.shape == (n_tiles + 1,) and key_start[-1] == len(pairs)
    assert len(pairs) < 0.1 * K * n_tiles
    for k in (0, 1, 2):
        assert k not in set(pairs.tolist())
    # within each tile the primitives are in ascending index order (compositing order)
    for t in range(n_tiles):
        seg = pairs[key_start[t] : key_start[t + 1]]
        assert np.all(np.diff(seg) > 0)
    # conservative: every tile on which a primitive has a non-zero alpha holds that pair
    alpha = rasterize_dense(means.view(K, 1, 2), covs.view(K, 1, 2, 2), opac.view(K, 1), torch.ones(1, 1), H, W)[:, 0]  # [K,H,W]
    pad = torch.zeros(K, nty * tile, ntx * tile)
    pad[:, :H, :W] = alpha
    touched = pad.view(K, nty, tile, ntx, tile).amax((2, 4)).reshape(K, n_tiles) > 0
    listed = torch.zeros(K, n_tiles, dtype=torch.bool)
    for t in range(n_tiles):
        listed[torch.from_numpy(pairs[key_start[t] : key_start[t + 1]]), t] = True
    assert touched.sum() > K  # the scene is not empty
    assert not (touched & ~listed).any()
    assert listed[3:].sum() <= 3 * touched[3:].sum()  # the bounding boxes are reasonably tight


def test_bin_pairs_batched_keys() -> None:
    # Keys are b * n_tiles + tile: the same primitive geometry in batch 1 lands in batch 1's range.
    H, W, tile = 16, 24, 8
    means = torch.tensor([[[4.0, 4.0], [20.0, 12.0]], [[20.0, 12.0], [4.0, 4.0]]])
    covs = torch.eye(2).expand(2, 2, 2) * 0.5
    opac = torch.full((2, 2), 0.8)
    pairs, key_start, ntx, nty = _pairs(means, covs, opac, H, W, tile)
    n_tiles = ntx * nty
    assert n_tiles == 6
    seg = lambda key: pairs[key_start[key] : key_start[key + 1]].tolist()  # noqa: E731
    assert seg(0) == [0] and seg(5) == [1]  # batch 0: prim 0 top-left, prim 1 bottom-right
    assert seg(n_tiles + 0) == [3] and seg(n_tiles + 5) == [2]  # batch 1 (flattened index b*K + k)
    assert len(pairs) == 4


# ----------------------------------------------------------------------------- errors
def test_backend_errors() -> None:
    means, covs, opac, colors = _scene(1, 5, 8, 8, seed=0)
    with pytest.raises(RuntimeError, match="gsplat"):
        rasterize(means, covs, opac, colors, 8, 8, backend="gsplat")
    with pytest.raises(ValueError, match="unknown rasterizer backend"):
        rasterize(means, covs, opac, colors, 8, 8, backend="opengl")  # type: ignore[arg-type]


@pytest.mark.parametrize("fn", [rasterize_dense, rasterize_tiles, rasterize_cpu])
def test_bad_shapes_raise(fn) -> None:
    B, K = 2, 5
    m, c, o, col = torch.zeros(B, K, 2), torch.eye(2).expand(K, 2, 2), torch.full((B, K), 0.5), torch.rand(K, 3)
    fn(m, c, o, col, 8, 8)  # the well-formed call works
    bad = [
        (torch.zeros(K, 2), c, o, col),  # means not batched
        (torch.zeros(B, K, 3), c, o, col),  # means not 2-D points
        (m, c, torch.full((B, K + 1), 0.5), col),  # opacities
        (m, torch.eye(3).expand(K, 3, 3), o, col),  # covariances 3x3
        (m, torch.eye(2).expand(B + 1, K, 2, 2), o, col),  # covariances wrong batch
        (m, c, o, torch.rand(K + 1, 3)),  # colours wrong K
        (m, c, o, torch.rand(B + 1, K, 3)),  # colours wrong batch
        (m, c, o, torch.rand(B, K)),  # colours without a channel axis
    ]
    for args in bad:
        with pytest.raises(ValueError):
            fn(*args, 8, 8)


# ----------------------------------------------------------------------------- gsplat (CUDA machines only)
needs_gsplat = pytest.mark.skipif(not gsplat_available(), reason="needs the gsplat package and a CUDA device")


def _cuda(*ts):
    return tuple(None if t is None else t.cuda() for t in ts)


@needs_gsplat
@pytest.mark.parametrize("HW", [(37, 51), (16, 16), (64, 40)])
@pytest.mark.parametrize("B", [1, 3])
def test_gsplat_equals_dense_where_the_rules_coincide(HW, B) -> None:
    """Below opacity 0.35 the 1/255 cut lies inside 3 sigma and the 0.99 cap is
    never reached, so gsplat's kernels and this module's rule draw the same image
    (up to gsplat stopping a pixel at transmittance 1e-4) and the same gradients."""
    H, W = HW
    means, covs, opac, colors = _scene(B, 48, H, W, seed=H * W + B, cov_batched=B > 1, col_batched=B > 1)
    opac = opac.clamp(max=0.34)
    bg = torch.tensor([0.2, 0.55, 0.9])
    ref = rasterize_dense(means, covs, opac, colors, H, W, bg)
    out = rasterize_gsplat(*_cuda(means, covs, opac, colors), H, W, bg.cuda())
    assert out.device.type == "cuda" and out.shape == ref.shape
    torch.testing.assert_close(out.cpu(), ref, atol=1e-4, rtol=0)
    up = torch.randn(B, 3, H, W, generator=torch.Generator().manual_seed(5))
    g_ref = _grads(rasterize_dense, means, covs, opac, colors, H, W, bg, up)
    g_out = _grads(R.rasterize_gsplat, *_cuda(means, covs, opac, colors), H, W, bg.cuda(), up.cuda())
    for g, r, n in zip(g_out, g_ref, ("means", "covs", "opacities", "colors")):
        assert r.abs().max() > 0, n
        _assert_rel(g.cpu(), r, 1e-3, f"gsplat d/d{n}")


@needs_gsplat
def test_gsplat_departs_from_the_rule_only_by_its_documented_tails(monkeypatch) -> None:
    """Decoder-like opacities (up to 0.99): the only departures are the tails beyond
    3 sigma that gsplat draws (alpha <= 0.011 o each), so the image stays within a
    few hundredths of the rule, and drawing those tails in the reference (no
    ``d2 <= 9`` cut) removes most of the difference."""
    H, W = 64, 64
    means, covs, opac, colors = _scene(2, 64, H, W, seed=11)
    opac = opac.clamp(max=0.99)
    ref = rasterize_dense(means, covs, opac, colors, H, W)
    out = rasterize_gsplat(*_cuda(means, covs, opac, colors), H, W).cpu()
    diff = (out - ref).abs()
    prepare = prepare_gaussians

    def prepare_without_3sigma_cut(means, covs, opacities, colors, eps2d):
        B, K, conic, colors, _, sxx, syy = prepare(means, covs, opacities, colors, eps2d)
        return B, K, conic, colors, 2.0 * torch.log(255.0 * opacities.clamp_min(1e-30)), sxx, syy

    monkeypatch.setattr(R, "prepare_gaussians", prepare_without_3sigma_cut)  # the name rasterize_dense calls
    tails = (out - rasterize_dense(means, covs, opac, colors, H, W)).abs()
    print(f"gsplat vs rule: max {float(diff.max()):.4f}, mean {float(diff.mean()):.2e}, "
          f"pixels > 1e-4: {float((diff > 1e-4).float().mean()):.3f}; vs rule without the 3-sigma cut: "
          f"max {float(tails.max()):.2e}, mean {float(tails.mean()):.2e}")
    assert 1e-3 < float(diff.max()) < 0.03
    assert float(tails.mean()) < 0.2 * float(diff.mean())


@needs_gsplat
def test_auto_backend_picks_gsplat_for_cuda_tensors() -> None:
    H, W = 21, 30
    means, covs, opac, colors = _cuda(*_scene(2, 30, H, W, seed=3))
    bg = torch.tensor([0.1, 0.2, 0.3]).cuda()
    auto = rasterize(means, covs, opac, colors, H, W, bg, backend="auto")
    direct = rasterize_gsplat(means, covs, opac, colors, H, W, bg)
    assert torch.equal(auto, direct)
    torch_cuda = rasterize(means, covs, opac, colors, H, W, bg, backend="torch")
    assert torch_cuda.device.type == "cuda"
    torch.testing.assert_close(torch_cuda.cpu(), rasterize_dense(*(t.cpu() for t in (means, covs, opac, colors)), H, W, bg.cpu()), atol=1e-5, rtol=0)


# ----------------------------------------------------------------------------- forward-mode AD
def test_jvp_of_tiles_equals_finite_difference() -> None:
    H, W = 19, 26
    means, covs, opac, colors = _scene(2, 30, H, W, seed=21, cov_batched=True, col_batched=True, dtype=torch.float64)
    bg = torch.tensor([0.2, 0.4, 0.6], dtype=torch.float64)
    gen = torch.Generator().manual_seed(22)
    tangents = tuple(torch.randn(t.shape, generator=gen, dtype=torch.float64) for t in (means, covs, opac, colors))
    tangents = (tangents[0], 0.5 * (tangents[1] + tangents[1].transpose(-1, -2)), 0.01 * tangents[2], tangents[3])

    def f(m, c, o, col):
        return rasterize_tiles(m, c, o, col, H, W, bg, tile=8)

    primals = (means, covs, opac, colors)
    out, tan = torch.func.jvp(f, primals, tangents)
    torch.testing.assert_close(out, rasterize_dense(means, covs, opac, colors, H, W, bg), rtol=0, atol=1e-12)
    e = 1e-6
    fd = (f(*(p + e * t for p, t in zip(primals, tangents))) - f(*(p - e * t for p, t in zip(primals, tangents)))) / (2 * e)
    assert tan.abs().max() > 0.1
    torch.testing.assert_close(tan, fd, rtol=0, atol=1e-5 * float(tan.abs().max()))
    # and the tangent along the means alone agrees with reverse mode (J v = sum over pixels)
    zeros = tuple(torch.zeros_like(p) for p in primals)
    _, tan_m = torch.func.jvp(f, primals, (tangents[0],) + zeros[1:])
    m_ = means.clone().requires_grad_(True)
    up = torch.randn(out.shape, generator=gen, dtype=torch.float64)
    (gm,) = torch.autograd.grad((f(m_, covs, opac, colors) * up).sum(), m_)
    torch.testing.assert_close((tan_m * up).sum(), (gm * tangents[0]).sum(), rtol=1e-9, atol=1e-12)


def test_compiled_rasterisation_keeps_torch_thread_count() -> None:
    """``threads=`` survives the numba kernels (numba's OpenMP layer resets the shared thread count
    at its first parallel launch), else results depend on the machine's core count.

    Run in a fresh interpreter: the reset happens at numba's first parallel launch only.
    """
    import os
    import subprocess
    import sys

    if (os.cpu_count() or 1) < 2:
        pytest.skip("needs 2 cores to show the effect")
    code = (
        "import torch; torch.set_num_threads(1)\n"
        "from lagsplat.render.rasterize import rasterize\n"
        "rasterize(torch.rand(1, 10, 2) * 16, torch.eye(2).expand(10, 2, 2).clone(), torch.rand(1, 10), torch.rand(10, 3), 16, 16, backend='cpu')\n"
        "print(torch.get_num_threads())\n"
    )
    env = {**os.environ, "NUMBA_NUM_THREADS": "2"}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip().splitlines()[-1] == "1"


# ----------------------------------------------------------------------------- compiled kernels
def _tile_crossing_scene(B: int, K: int, H: int, W: int, C: int, seed: int):
    """Random 1-8 px primitives inside the image (most cross a 16-px tile edge), 40 % of
    the opacities in [0.95, 0.985] (near 1, where ``1 / (1 - alpha)`` amplifies
    rounding), four above the 0.99 cap, ``C`` colour channels."""
    g = torch.Generator().manual_seed(seed)
    means = torch.rand(B, K, 2, generator=g) * torch.tensor([float(W), float(H)])
    std = torch.exp(torch.empty(K, 2).uniform_(0.0, math.log(8.0), generator=g))
    covs = _rotated_covs(std, torch.rand(K, generator=g) * math.pi)
    near1 = torch.rand(B, K, generator=g) < 0.4
    opac = torch.where(near1, 0.95 + 0.035 * torch.rand(B, K, generator=g), 0.1 + 0.7 * torch.rand(B, K, generator=g))
    opac[:, :4] = 1.2
    return means, covs, opac, torch.rand(B, K, C, generator=g)


@pytest.mark.parametrize(
    "H,W,B,C,seed",
    [(37, 51, 2, 3, 0), (40, 33, 1, 5, 1), (16, 64, 3, 3, 2), (70, 70, 1, 4, 3), (64, 64, 4, 3, 5)],
)
def test_cpu_gradients_equal_dense_in_double_to_1e_5(H, W, B, C, seed) -> None:
    """The compiled backward pass against the dense rule evaluated in float64, to 1e-5 of each gradient's scale.

    (On :func:`_scene`, whose sub-pixel primitives put pixels within float32
    rounding of the cut and the cap, float32 itself moves those pixels across
    the discontinuity: there every float32 backend, the dense reference
    included, is 1e-5 to 3e-5 off float64, and the test above uses 1e-4.)
    """
    means, covs, opac, colors = _tile_crossing_scene(B, 40, H, W, C, seed)
    bg = torch.rand(C, generator=torch.Generator().manual_seed(seed + 1))
    up = torch.randn(B, C, H, W, generator=torch.Generator().manual_seed(seed + 2))
    ref = _grads(rasterize_dense, *(t.double() for t in (means, covs, opac, colors)), H, W, bg.double(), up.double())
    got = _grads(rasterize_cpu, means, covs, opac, colors, H, W, bg, up)
    ex = torch.sqrt(9.0 * (covs[:, 0, 0] + EPS2D))
    assert bool(((means[..., 0] - ex) // 16 != (means[..., 0] + ex) // 16).any())  # supports cross tile edges
    for g, r, n in zip(got, ref, ("means", "covs", "opacities", "colors")):
        assert g.dtype == torch.float32 and g.shape == r.shape and r.abs().max() > 0
        _assert_rel(g.double(), r, 1e-5, f"cpu d/d{n}")


def test_exp_polynomial_is_within_one_ulp_on_the_cut_range() -> None:
    """Both forms of :func:`cpu_kernels.exp_neg` against float64 ``exp`` on ``[-4.5, 0]`` (every float32 alpha
    the rule keeps), and bit for bit against each other (the kernels' choice by target changes no image)."""
    from numba import njit

    def runner(f):
        @njit
        def run(x):  # pragma: no cover - compiled
            out = np.empty_like(x)
            for i in range(x.shape[0]):
                out[i] = f(x[i])
            return out

        return run

    x = np.linspace(-4.5, 0.0, 200_001).astype(np.float32)
    ref = np.exp(x.astype(np.float64))
    outs = []
    for f in (ck.exp_neg_shift, ck.exp_neg_select):
        run = runner(f)
        out = run(x)
        rel = np.abs(out.astype(np.float64) - ref) / ref
        assert rel.max() < 2.0e-7  # float32 ulp at 1 is 1.19e-7
        assert run(np.array([0.0], np.float32))[0] == 1.0
        assert run(np.array([-50.0], np.float32))[0] == pytest.approx(math.exp(-4.5), rel=2e-7)  # clamped
        outs.append(out)
    assert np.array_equal(outs[0], outs[1])
    assert ck.exp_neg in (ck.exp_neg_shift, ck.exp_neg_select)


_GRAD_SCRIPT = """
import sys, numpy as np, torch
torch.manual_seed(0)
from lagsplat.render.rasterize import rasterize
B, K, H, W = 2, 300, 32, 32
means = (torch.rand(B, K, 2) * 32).requires_grad_(True)
A = torch.randn(K, 2, 2) * 1.5
covs = (A @ A.transpose(-1, -2) + 0.5 * torch.eye(2)).requires_grad_(True)
op = torch.rand(B, K).requires_grad_(True)
col = torch.rand(B, K, 3).requires_grad_(True)
rasterize(means, covs, op, col, H, W, backend="cpu").square().sum().backward()
np.savez(sys.argv[1], *[t.grad.numpy() for t in (means, covs, op, col)])
"""


def test_freshly_compiled_and_cached_kernels_give_the_same_gradients(tmp_path) -> None:
    # the first process compiles the kernels into an empty cache, the second loads them: a run on a fresh
    # checkout must train exactly like every later run
    pytest.importorskip("numba")
    import os
    import subprocess
    import sys

    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    script = tmp_path / "grads.py"
    script.write_text(_GRAD_SCRIPT)
    for k in (1, 2):
        subprocess.run([sys.executable, str(script), str(tmp_path / f"g{k}.npz")], env=env, check=True, timeout=600)
    a, b = np.load(tmp_path / "g1.npz"), np.load(tmp_path / "g2.npz")
    assert all(np.array_equal(a[k], b[k]) for k in a.files)
