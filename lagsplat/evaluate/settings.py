"""Settings of the evaluation protocols (``conf/config.yaml`` group ``evaluate``; ``krauss_eval`` of
``conf/system/krauss_*.yaml``): plain dataclasses, importable without the protocols' numerical modules (the configuration
schema reads them at every stage's start-up)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

from lagsplat.train.config import dataclass_from_mapping

__all__ = ["EvalConfig", "KraussEvalConfig"]


@dataclass
class EvalConfig:
    """Evaluation settings (``conf/config.yaml``, group ``evaluate``)."""

    n_windows: int = 50
    seed: int = 0
    n_periods: float = 2.0
    sigma: float = 1.0
    freq_window_periods: float = 8.0
    min_amplitude: float = 0.05
    render_batch: int = 64


@dataclass
class KraussEvalConfig:
    """Settings of the published protocol (``krauss_eval`` group of ``conf/system/krauss_*.yaml``).

    Defaults are the published values (the reference code); ``period_s`` is
    the two-segment one (``--period-s 0.6870``).

    Attributes:
        horizon_s: multi-step MSE horizon, s (30 states at 59.94 fps).
        n_windows: rollout starts for the MSE and the cycle error.
        seed: seed of ``numpy.random.default_rng`` drawing them.
        skip_s: static head skipped at the start of the validation clip, s (480 frames).
        sigma: Gaussian smoothing of the encodings, frames.
        sigma_pressure: Gaussian smoothing of the pressures, frames.
        ae_frames: frames of the AE floor (``linspace`` over ``[skip, n-1]``).
        flat_step_tol: a frame is flat if every chamber moved less than this
            fraction of the pressure amplitude since the previous frame.
        flat_total_tol: a flat run is discarded if its peak-to-peak exceeds
            this fraction of the amplitude.
        min_flat_s: shortest free-oscillation interval, s (120 frames).
        max_intervals: intervals kept, longest first.
        freq_window_periods: analysis window length in periods of ``f0``.
        min_window: shortest analysis window, frames.
        min_amplitude: windows with G-RMS amplitude below this fraction of
            ``q_std`` are skipped.
        diverge_factor: a rollout beyond ``diverge_factor * max |q_enc|`` is rejected.
        cycle_periods, period_s: cycle-error horizon ``round(cycle_periods * period_s / dt)``.
        trim_duplicates: trim leading duplicated frames before §9.2.
        render_batch: decoder batch size.
    """

    horizon_s: float = 0.5
    n_windows: int = 50
    seed: int = 0
    skip_s: float = 8.0
    sigma: float = 1.0
    sigma_pressure: float = 1.0
    ae_frames: int = 1000
    flat_step_tol: float = 0.01
    flat_total_tol: float = 0.05
    min_flat_s: float = 2.0
    max_intervals: int = 20
    freq_window_periods: float = 8.0
    min_window: int = 16
    min_amplitude: float = 0.05
    diverge_factor: float = 2.0
    cycle_periods: float = 2.0
    period_s: float = 0.6870
    trim_duplicates: bool = True
    render_batch: int = 64

    @classmethod
    def from_mapping(cls, m: Mapping[str, Any] | None) -> "KraussEvalConfig":
        """Build from a (Hydra) mapping; ``None`` gives the defaults; unknown keys raise ``KeyError``."""
        return cls() if not m else dataclass_from_mapping(cls, m, "krauss_eval")
