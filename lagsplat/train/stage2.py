"""Stage 2: fit the latent Lagrangian to the encoded trajectory (paper §3.3, Eq. 8)."""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from torch import Tensor

from lagsplat import metrics, timeseries
from lagsplat.chart import Chart
from lagsplat.dynamics.integrators import actuation_schedule, initial_state, rollout
from lagsplat.io.atomic import save_torch
from lagsplat.io.clip import TRAIN
from lagsplat.train.device import resolve_device
from lagsplat.train.progress import Progress
from lagsplat.train.shooting import multi_step_windows, shooting_loss
from lagsplat.train.stage2_config import PAPER_FIT, Mass, Potential, Stage2Config
from lagsplat.models.icnn import ConcaveMap
from lagsplat.models.inertia import DecoderInertia
from lagsplat.models.lagrangian import Lagrangian

__all__ = ["PAPER_FIT", "Stage2Config", "Mass", "Potential", "one_step_windows", "selection_replaces", "TrainingWindows", "training_windows", "train_stage2", "save_stage2", "load_stage2"]


def one_step_windows(q: np.ndarray, dt: float, k: int, u: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    """Training pairs of Eq. 8 from one contiguous trajectory (the reference code).

    For every ``s``: state ``(q[s+k], (q[s+2k] - q[s]) / 2k dt)`` and target
    ``(q[s+2k], (q[s+3k] - q[s+k]) / 2k dt)``, one step of ``h = k dt``.

    Args:
        q: ``[n,d]`` (smoothed) trajectory.
        dt: frame interval, seconds.
        k: stride in frames.
        u: ``[n,n_u]`` actuation per frame, or ``None``.

    Returns:
        ``(q0, v0, q1, v1, u0, u1)``, each ``[n - 3k, .]``: ``u0``/``u1`` the
        actuation at the start / end of the step (``[n - 3k, 0]`` without actuation).
    """
    q0, v0, Q, V, U = multi_step_windows(q, dt, k, 1, u)
    return q0, v0, Q[:, 0], V[:, 0], U[:, 0], U[:, 1]


def selection_replaces(err: float, best_err: float, best_epoch: int, cfg: Stage2Config) -> bool:
    """Whether an epoch whose selection rollouts scored ``err`` replaces the kept model (scored ``best_err`` at
    ``best_epoch``): a lower error, or any finite one while the kept model is from before ``select_from * epochs``."""
    return err < best_err or (best_epoch < cfg.select_from * cfg.epochs and bool(np.isfinite(err)))


def _lagrangian(model: torch.nn.Module) -> Lagrangian | None:
    """``model`` itself if a :class:`Lagrangian`, the one an augmented module holds as ``base``, or ``None``."""
    lag = model if isinstance(model, Lagrangian) else getattr(model, "base", None)
    return lag if isinstance(lag, Lagrangian) else None


def _actuation_map(model: torch.nn.Module) -> ConcaveMap | None:
    """The actuation map of ``model``'s Lagrangian (:func:`_lagrangian`), or ``None``."""
    lag = _lagrangian(model)
    return None if lag is None else lag.actuation


def _param_groups(model: torch.nn.Module, cfg: Stage2Config) -> list[dict]:
    """Adam's parameter groups: the potential ICNN's input layers at ``lr * lr_potential_input``, the rest at ``lr``
    (``model`` may be an augmented module holding the Lagrangian as ``base``)."""
    lag = _lagrangian(model)
    fast = [] if lag is None else list(lag.potential_hat.g.inp.parameters())
    ids = {id(p) for p in fast}
    rest = [p for p in model.parameters() if id(p) not in ids]
    groups = [{"params": rest, "lr": cfg.lr}]
    if fast:
        groups.append({"params": fast, "lr": cfg.lr * cfg.lr_potential_input})
    return groups


def _rollout_error(
    model: Lagrangian, q: np.ndarray, dt: float, G: np.ndarray, horizon: int, starts: np.ndarray, q_std: float, u: np.ndarray | None = None
) -> float:
    """Latent NRMSE in ``G`` of rollouts of ``horizon`` states from ``starts`` of ``q`` (driven by ``u [n,n_u]`` if given)."""
    q0, v0 = initial_state(q, starts, dt)
    u_w = None if u is None or u.shape[1] == 0 else np.stack([u[s : s + horizon] for s in starts])
    pred, _ = rollout(model, q0, v0, dt, horizon, u=actuation_schedule(u_w, dt))
    true = np.stack([q[s : s + horizon] for s in starts])
    pred = pred.numpy()
    if not np.isfinite(pred).all():
        return float("inf")
    return metrics.latent_nrmse(pred, true, G, q_std)


@dataclass
class TrainingWindows:
    """What Stage 2 (and a baseline trained like it) reads from the chart's training frames (paper Eq. 8, §3.3).

    Attributes:
        dt: frame period, s.
        q_smooth: the training segments' smoothed ``q`` (``cfg.sigma`` frames), each ``[m_i,d]``.
        u_segs: their actuation, each ``[m_i,n_u]``.
        Q0, V0, Q1, V1, U0, U1: the one-step windows of :func:`one_step_windows`, concatenated, float32 tensors.
        G: trace-normalised ``G_bar`` (the selection's NRMSE metric).
        f_train: spectral peak of the longest segment along the most visible direction, Hz.
        select_q, select_u: the longest segment (the selection's rollouts run over it) and its actuation.
        select_starts, select_horizon: the selection rollouts' start frames and length, states.
        q_std: the longest segment's ``G``-weighted rms spread (the NRMSE scale).
        shooting: the ``cfg.rollout_steps``-step windows of :func:`~lagsplat.train.shooting.multi_step_windows`
            ``(q0, v0, Q, V, U)``, concatenated, float32 tensors (``K = 1``: the one-step windows); their
            velocities are one-frame central differences where ``substeps > 1``.
        substeps: Verlet steps per training step (:meth:`Stage2Config.substeps` at ``f_train``).
    """

    dt: float
    q_smooth: list
    u_segs: list
    Q0: Tensor
    V0: Tensor
    Q1: Tensor
    V1: Tensor
    U0: Tensor
    U1: Tensor
    G: np.ndarray
    f_train: float
    select_q: np.ndarray
    select_u: np.ndarray
    select_starts: np.ndarray
    select_horizon: int
    q_std: float
    shooting: tuple
    substeps: int = 1


def training_windows(chart: Chart, cfg: Stage2Config, seed: int = 0, what: str = "stage-2", select_share: float = 1.0) -> TrainingWindows:
    """The one-step windows and the selection set-up of the chart's training frames (:class:`TrainingWindows`).

    The selection rollouts run ``cfg.select_periods`` natural periods, at most ``select_share`` of the longest
    training segment (``1``: up to all of it, from one start when it is shorter than the horizon; ``0.5`` for
    a clip identified on all its frames, so that the rollouts start at several phases of the motion rather
    than once from the clip's first frame, whose state may not be a free motion's).

    Raises:
        ValueError: if no training segment is long enough for one window (``what`` names the model).
    """
    dt = float(np.median(np.diff(chart.t)))
    segs = [s for s in chart.segments(TRAIN) if len(s) > 3 * cfg.stride + 3]
    if not segs:
        raise ValueError(f"no training segment is long enough for one {what} window")
    q_smooth = [timeseries.gaussian_smooth(chart.q[s], cfg.sigma) for s in segs]
    u_segs = [chart.u[s] for s in segs]
    wins = [one_step_windows(qs, dt, cfg.stride, us) for qs, us in zip(q_smooth, u_segs)]
    Q0, V0, Q1, V1, U0, U1 = (torch.as_tensor(np.concatenate([w[i] for w in wins]), dtype=torch.float32) for i in range(6))
    G = metrics.normalise_trace(chart.G_bar)
    i_long = int(np.argmax([len(x) for x in q_smooth]))
    longest = q_smooth[i_long]
    f_train = timeseries.spectral_peak_frequency(metrics.project(longest, metrics.top_direction(chart.G_bar)), dt)
    K = cfg.effective_rollout_steps(chart.d)
    substeps = cfg.substeps(f_train, dt)
    k_v = 1 if substeps > 1 else cfg.stride
    multi = [multi_step_windows(qs, dt, cfg.stride, K, us, k_v) for qs, us in zip(q_smooth, u_segs)]
    shooting = tuple(torch.as_tensor(np.concatenate([w[i] for w in multi]), dtype=torch.float32) for i in range(5))
    if len(shooting[0]) == 0:
        raise ValueError(f"no training segment is long enough for one {what} window of {K} steps (stage2.rollout_steps)")
    horizon = max(8, int(round(cfg.select_periods / (f_train * dt))))
    if select_share < 1.0:
        horizon = max(8, min(horizon, int(select_share * len(longest))))
    hi = len(longest) - horizon - 2
    starts = metrics.window_starts(0, hi, cfg.select_windows, seed) if hi > 0 else np.zeros(1, int)
    return TrainingWindows(dt, q_smooth, u_segs, Q0, V0, Q1, V1, U0, U1, G, f_train, longest, u_segs[i_long], starts,
                           min(horizon, len(longest) - 2), metrics.g_rms_spread(longest, G), shooting, substeps)  # fmt: skip


def train_stage2(
    chart: Chart,
    cfg: Stage2Config,
    seed: int = 0,
    progress: bool = True,
    inertia: DecoderInertia | None = None,
    augment: Callable[[Lagrangian], torch.nn.Module] | None = None,
    n_u_model: int | None = None,
    device: str = "cpu",
    label: str = "stage2",
    select_share: float = 1.0,
) -> tuple[Lagrangian, dict]:
    """Fit the Lagrangian by one differentiable Verlet step per window (Eq. 8).

    The loss is ``w_q |q1_hat - q1|_A^2 / d + w_v |h (v1_hat - v1)|_A^2 / d`` with ``A``
    the chart's loss metric. Every ``select_every`` epochs the model is rolled
    out freely over ``select_periods`` natural periods from seeded starts on the
    *training* frames; of the epochs from ``select_from * epochs`` on, the state with the
    lowest latent NRMSE is returned (model selection on multi-step rollout error, paper §3.3;
    ``select_from = 1`` keeps the last epoch, falling back to an earlier one only when its
    rollouts are not finite). With ``cfg.potential_kinks_alternatives`` (and no ``augment``)
    the fit is run once per kink sharpness from the same seed, and the start whose selected
    state scored lowest is returned.

    Args:
        chart: the frozen chart (only its training frames are used; several
            training episodes give one model, multi-clip training). Its
            actuation ``chart.u`` (if any) drives the model (paper Eq. 6).
        cfg: settings.
        seed: RNG seed.
        progress: report progress (:class:`~lagsplat.train.progress.Progress`:
            a tqdm bar on a terminal, a line every ~30 s otherwise).
        inertia: the :class:`DecoderInertia` when ``cfg.mass == "decoder"``.
        augment: hook for the gap-diagnosis refit (:mod:`lagsplat.diagnose.refit`):
            called once with the built Lagrangian after its rest state and energy
            gauge are set, it returns the module that is trained and selected
            instead (e.g. the fitted weights loaded and effect terms added,
            :class:`~lagsplat.diagnose.terms.AugmentedLagrangian`); it must keep
            the ``acceleration(q, qdot, f_ext, u=...)`` interface. ``None``: the plain model.
        n_u_model: actuation channels the Lagrangian itself reads (default
            ``chart.n_u``); the chart's channels beyond it are for ``augment``'s
            module (e.g. the clip time of a time-dependent term).
        device: ``"cpu"`` (the reference), ``"cuda"`` or ``"auto"``
            (:func:`~lagsplat.train.device.resolve_device`): the model is
            built on the CPU, its one-step windows are trained on the device,
            the selection rollouts run on a CPU copy, and the model is
            returned on the CPU.
        label: what the progress report is headed with (e.g. ``"toy stage2"``).
        select_share: the selection rollouts' longest horizon as a share of the longest training
            segment (:func:`training_windows`; 0.5 for a clip without held-out frames).

    Returns:
        ``(model, history)``; ``model`` is ``augment``'s module when given. ``history`` holds
        per epoch ``epoch`` and ``loss``, ``select_nrmse`` as ``(epoch, NRMSE)`` pairs,
        ``selected_epoch``, ``selected_nrmse`` and ``f_train_hz`` (Hz); with several starts, those of
        the start kept, plus ``potential_kinks`` (its sharpness) and ``starts`` (per start its
        ``potential_kinks``, ``selected_nrmse`` and ``selected_epoch``).

    Raises:
        ValueError: if the training segment is too short for one window, or
            ``mass="decoder"`` without ``inertia``.
    """
    d, n_u = chart.d, chart.n_u
    starts = [cfg.effective_kinks(d, n_u)]
    if augment is None and starts[0] > 0:
        starts += [s for s in dict.fromkeys(map(float, cfg.potential_kinks_alternatives)) if s != starts[0]]
    w = training_windows(chart, cfg, seed, "stage-2", select_share)
    if len(starts) == 1:
        return _fit(chart, w, cfg, seed, progress, inertia, augment, n_u_model, device, label, starts[0])
    fits = [_fit(chart, w, cfg, seed, progress, inertia, augment, n_u_model, device, f"{label} (kinks {s:g})", s) for s in starts]
    best = min(range(len(fits)), key=lambda i: fits[i][1]["selected_nrmse"])
    model, hist = fits[best]
    hist["starts"] = [{"potential_kinks": s, "selected_nrmse": h["selected_nrmse"], "selected_epoch": h["selected_epoch"]} for s, (_, h) in zip(starts, fits)]
    hist["potential_kinks"] = starts[best]
    return model, hist


def _fit(
    chart: Chart, w: TrainingWindows, cfg: Stage2Config, seed: int, progress: bool, inertia: DecoderInertia | None,
    augment: Callable[[Lagrangian], torch.nn.Module] | None, n_u_model: int | None, device: str, label: str, kinks: float,
) -> tuple[Lagrangian, dict]:  # fmt: skip
    """One start of :func:`train_stage2` on the chart's windows ``w`` (shared by the starts), its potential's kinks
    spread at sharpness ``kinks`` (0: at the origin)."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    dt, d, q_smooth, f_train, G_eval = w.dt, chart.d, w.q_smooth, w.f_train, w.G
    n_u = chart.n_u
    A = torch.as_tensor(chart.A, dtype=torch.float32)

    # Observed natural frequency on the training frames fixes the energy gauge
    # and the selection horizon (nothing from held-out frames is used here).
    model = cfg.build(d, n_u if n_u_model is None else int(n_u_model), inertia)
    with torch.no_grad():
        model.potential_hat.q_rest.copy_(torch.as_tensor(np.concatenate(q_smooth).mean(0), dtype=torch.float32))
    if kinks > 0:
        model.potential_hat.g.spread_kinks(torch.as_tensor(np.concatenate(q_smooth), dtype=torch.float32), kinks, seed)
    model.init_energy_scales(2 * math.pi * f_train, cfg.zeta_floor)
    if augment is not None:
        model = augment(model)

    dev = resolve_device(device)
    model = model.to(dev)
    A = A.to(dev)
    S0, SV0, SQ, SV, SU = (t.to(dev) for t in w.shooting)
    sel_seg, sel_u, q_std, sel_starts, sel_h = w.select_q, w.select_u, w.q_std, w.select_starts, w.select_horizon

    h = cfg.stride * dt
    opt = torch.optim.Adam(_param_groups(model, cfg), lr=cfg.lr)
    n = len(S0)
    hist: dict[str, list] = {"epoch": [], "loss": [], "select_nrmse": []}
    best = (float("inf"), copy.deepcopy(model.state_dict()), -1)
    bar = Progress(cfg.epochs, label, enabled=progress, unit="epoch")
    for ep in bar:
        model.train()
        perm = rng.permutation(n)[: min(n, cfg.windows_per_epoch)]
        tot, cnt = 0.0, 0
        for i in range(0, len(perm), cfg.batch):
            b = torch.as_tensor(perm[i : i + cfg.batch], device=dev)
            loss = shooting_loss(model, S0[b], SV0[b], SQ[b], SV[b], SU[b], h, A, cfg.w_q, cfg.w_v, w.substeps)
            act = _actuation_map(model)
            if cfg.w_actuation_linear > 0 and act is not None:
                loss = loss + cfg.w_actuation_linear * act.nonlinearity(S0[b])
            if not torch.isfinite(loss):
                continue  # skip a diverged batch (the reference code)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
            opt.step()
            tot, cnt = tot + float(loss.detach()), cnt + 1
        hist["epoch"].append(ep)
        hist["loss"].append(tot / max(cnt, 1))
        if (ep + 1) % cfg.select_every == 0 or ep == cfg.epochs - 1:
            model.eval()
            on_cpu = model if dev.type == "cpu" else copy.deepcopy(model).cpu()
            err = _rollout_error(on_cpu, sel_seg, dt, G_eval, sel_h, sel_starts, q_std, sel_u)
            hist["select_nrmse"].append((ep, err))
            if selection_replaces(err, best[0], best[2], cfg):
                best = (err, copy.deepcopy(model.state_dict()), ep)
            bar.update(loss=hist["loss"][-1], select_nrmse=err)
    model.load_state_dict(best[1])
    model = model.cpu()
    hist["selected_epoch"] = best[2]
    hist["selected_nrmse"] = best[0]
    hist["f_train_hz"] = f_train
    hist["substeps"] = w.substeps
    return model.eval(), hist


def save_stage2(path: str | Path, model: Lagrangian, cfg: Stage2Config, history: dict) -> Path:
    """Write ``stage2.pt`` atomically: weights, settings and training history."""
    from dataclasses import asdict

    extra = {"n_u": model.n_u}
    if isinstance(model.mass_field, DecoderInertia):
        extra["n_gaussians"] = int(model.mass_field.J.shape[0])
    return save_torch(path, {"state_dict": model.state_dict(), "config": asdict(cfg), "d": model.d, "history": history, **extra})


def load_stage2(path: str | Path) -> tuple[Lagrangian, dict]:
    """Rebuild the Lagrangian saved by :func:`save_stage2` (eval mode).

    Raises:
        FileNotFoundError: if ``path`` does not exist.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: stage-2 checkpoint not found")
    ck = torch.load(path, map_location="cpu", weights_only=False)
    cfg = Stage2Config.from_mapping(ck["config"])
    inertia = DecoderInertia(ck["n_gaussians"], ck["d"]) if cfg.mass == "decoder" else None
    model = cfg.build(ck["d"], int(ck.get("n_u", 0)), inertia)
    model.load_state_dict(ck["state_dict"])
    return model.eval(), ck
