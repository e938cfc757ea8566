"""Evaluation protocols: a trained model scored on the clip's held-out frames (paper §4.1, §4.4).

Each protocol is a function ``(clip, ae, chart, model, settings, system,
source) -> metrics`` registered in :data:`PROTOCOLS` under the name a system
configuration gives as ``system.protocol``:

* ``paper`` (also ``default``, the value when a system names none): the
  paper's frequency error, latent NRMSE and image error over free rollouts
  (:mod:`lagsplat.evaluate.paper`), settings from the ``evaluate`` group; a
  simulated source whose ``system.truth`` names an NPZ with the true
  coordinate ``q [T0, ...]`` per source frame (e.g. :mod:`lagsplat.synth.pendulum3d`)
  is also scored against the true frequency on the held-out frames;
* ``krauss``: the published soft-robot protocol (:mod:`lagsplat.evaluate.krauss`),
  settings from the ``krauss_eval`` group, the simulator's truth from the
  sidecar JSON named by ``system.truth``.

The returned mapping is the ``metrics`` block of ``metrics.json`` (name ->
``{value, definition, horizon, units}``, :func:`~lagsplat.evaluate.common.metric_entry`).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Mapping

import numpy as np

from lagsplat.evaluate.settings import EvalConfig, KraussEvalConfig
from lagsplat.lazy import lazy_exports

if TYPE_CHECKING:
    from lagsplat.chart import Chart
    from lagsplat.io.clip import Clip
    from lagsplat.models.autoencoder import AutoEncoder

__all__ = ["EvalConfig", "evaluate", "KraussEvalConfig", "evaluate_krauss", "PROTOCOLS", "protocol_for", "run_protocol"]

Protocol = Callable[["Clip", "AutoEncoder", "Chart", Any, Mapping[str, Any], Mapping[str, Any], str], dict]


# the protocols' drivers, imported on first use (the configuration schema imports the settings above at every
# stage's start-up; the drivers pull in the image metrics)
__getattr__, __dir__ = lazy_exports(__name__, {"evaluate": "paper", "evaluate_krauss": "krauss"})


def observed_truth_frequency(clip: Clip, truth_path: str | Path) -> float:
    """The true frequency on the clip's held-out frames (Hz; on all its frames for a clip marked
    :attr:`~lagsplat.io.clip.Clip.no_held_out`): the spectral peak
    (:func:`lagsplat.timeseries.spectral_peak_frequency`) of the first coordinate of ``q`` in the NPZ
    ``truth_path``, one row per source frame (the clip's frames start at ``meta["frames"][0]``).

    Raises:
        FileNotFoundError: naming the file if it does not exist.
        ValueError: naming the file if it has no ``q`` or too few rows for the clip.
    """
    from lagsplat.timeseries import spectral_peak_frequency

    path = Path(truth_path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: simulator truth (system.truth) not found")
    with np.load(path) as z:
        if "q" not in z.files:
            raise ValueError(f"{path}: the truth needs q (the true coordinate per source frame)")
        q = np.asarray(z["q"], float).reshape(len(z["q"]), -1)[:, 0]
    # a clip identified on all its frames (Clip.no_held_out) is read in-sample: the truth over the whole clip
    idx = int((clip.meta.get("frames") or [0])[0] or 0) + (clip.held_out_idx if clip.no_held_out is None else np.arange(clip.n_frames))
    if len(idx) == 0 or idx[-1] >= len(q):
        raise ValueError(f"{path}: {len(q)} truth rows, the clip's held-out frames reach source frame {idx[-1] if len(idx) else '-'}")
    return float(spectral_peak_frequency(q[idx], clip.dt))


def paper_protocol(clip: Clip, ae: AutoEncoder, chart: Chart, model: Any, settings: Mapping[str, Any], system: Mapping[str, Any], source: str) -> dict:
    """The paper's protocol (:func:`lagsplat.evaluate.paper.evaluate`); ``settings``: the ``evaluate`` group; with an NPZ
    ``system.truth``, the true held-out frequency (:func:`observed_truth_frequency`) joins the clip's truth."""
    truth_path = system.get("truth")
    if truth_path and str(truth_path).endswith(".npz"):
        truth = {**clip.meta.get("truth", {}), "f_observed_hz": observed_truth_frequency(clip, truth_path)}
        clip = dataclasses.replace(clip, meta={**clip.meta, "truth": truth})
    from lagsplat.evaluate.paper import evaluate

    return evaluate(clip, ae, chart, model, EvalConfig(**dict(settings or {})), source=source)


def krauss_protocol(clip: Clip, ae: AutoEncoder, chart: Chart, model: Any, settings: Mapping[str, Any], system: Mapping[str, Any], source: str) -> dict:
    """The soft-robot protocol (:func:`lagsplat.evaluate.krauss.evaluate_krauss`); ``settings``: the ``krauss_eval`` group.

    Raises:
        FileNotFoundError: if ``system.truth`` names a sidecar that does not exist.
    """
    truth_path = system.get("truth")
    if truth_path and not Path(truth_path).exists():
        raise FileNotFoundError(f"{truth_path}: simulator truth sidecar (system.truth) not found")
    truth = json.loads(Path(truth_path).read_text()) if truth_path else None
    from lagsplat.evaluate.krauss import evaluate_krauss

    return evaluate_krauss(clip, ae, chart, model, KraussEvalConfig.from_mapping(settings or None), source=source, truth=truth)


PROTOCOLS: dict[str, Protocol] = {"paper": paper_protocol, "default": paper_protocol, "krauss": krauss_protocol}
"""Protocol name (``system.protocol``) -> protocol function."""

SETTINGS_GROUP = {"paper": "evaluate", "default": "evaluate", "krauss": "krauss_eval"}
"""Protocol name -> the configuration group holding its settings."""


def protocol_for(system: Mapping[str, Any]) -> str:
    """The protocol a system configuration names (``system.protocol``; ``default`` when unset).

    Raises:
        KeyError: naming the unknown protocol and the known ones.
    """
    name = str(system.get("protocol") or "default")
    if name not in PROTOCOLS:
        raise KeyError(f"unknown evaluation protocol system.protocol={name!r}; known: {sorted(PROTOCOLS)}")
    return name


def run_protocol(name: str, clip: Clip, ae: AutoEncoder, chart: Chart, model: Any, settings: Mapping[str, Any], system: Mapping[str, Any], source: str) -> dict:
    """Score ``model`` by protocol ``name`` (:data:`PROTOCOLS`); returns the ``metrics`` block of ``metrics.json``."""
    return PROTOCOLS[name](clip, ae, chart, model, settings, system, source)
