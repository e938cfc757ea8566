"""Synthetic clips with known physics (the embedded default data).

:func:`make_clip` builds a clip from a system configuration::

    source:
      synth: pendulum          # generator name, see GENERATORS
      params: {zeta: 0.02, ...} # keyword arguments of the generator
    split:
      train_fraction: 0.6      # optional, overrides params.train_fraction
                               # (coupled_carts: used only with n_episodes = 1;
                               # several episodes are split by episode)
    resize: [64, 64]           # optional [W, H], overrides params.size
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Mapping
from typing import Any

from lagsplat.io.clip import Clip
from lagsplat.synth.coupled_carts import CoupledCarts, simulate_coupled_carts
from lagsplat.synth.coupled_carts_clip import make_coupled_carts_clip, render_coupled_carts
from lagsplat.synth.effect_clips import make_effect_clip
from lagsplat.synth.pendulum import make_pendulum_clip, render_pendulum, simulate_pendulum

__all__ = [
    "make_clip",
    "GENERATORS",
    "make_pendulum_clip",
    "render_pendulum",
    "simulate_pendulum",
    "CoupledCarts",
    "make_coupled_carts_clip",
    "render_coupled_carts",
    "simulate_coupled_carts",
    "make_effect_clip",
]

#: Generator name (``source.synth``) -> clip factory.
GENERATORS: dict[str, Callable[..., Clip]] = {
    "pendulum": make_pendulum_clip,
    "coupled_carts": make_coupled_carts_clip,
    "effects": make_effect_clip,
}


def _to_plain(cfg: Any) -> Any:
    """Convert an OmegaConf container to plain Python; leave other objects alone."""
    try:
        from omegaconf import DictConfig, ListConfig, OmegaConf
    except ImportError:  # pragma: no cover - omegaconf is a dependency
        return cfg
    if isinstance(cfg, (DictConfig, ListConfig)):
        return OmegaConf.to_container(cfg, resolve=True)
    return cfg


def make_clip(system_cfg: Any) -> Clip:
    """Build the synthetic clip a system configuration asks for.

    Args:
        system_cfg: mapping (plain ``dict`` or OmegaConf ``DictConfig``) with
            ``source.synth`` (generator name, e.g. ``"pendulum"``) and optional
            ``source.params`` (keyword arguments of the generator),
            ``split.train_fraction`` (overrides the parameter of the same name;
            ``coupled_carts`` uses it only for a single episode, several
            episodes are split by episode) and ``resize`` (``[W, H]``, sets ``size``).

    Returns:
        The validated :class:`~lagsplat.io.clip.Clip`.

    Raises:
        ValueError: if ``source.synth`` is missing or names an unknown
            generator, or ``params`` is not a mapping or holds unknown keys.
    """
    cfg = _to_plain(system_cfg)
    if not isinstance(cfg, Mapping):
        raise ValueError(f"system config must be a mapping, got {type(system_cfg).__name__}")
    source = cfg.get("source")
    if not isinstance(source, Mapping) or "synth" not in source:
        raise ValueError("system config needs source.synth naming a synthetic generator")
    name = source["synth"]
    if not isinstance(name, str) or name not in GENERATORS:
        raise ValueError(f"unknown synthetic generator {name!r}; known: {sorted(GENERATORS)}")
    gen = GENERATORS[name]

    params = source.get("params") or {}
    if not isinstance(params, Mapping):
        raise ValueError(f"source.params must be a mapping, got {type(params).__name__}")
    kwargs = dict(params)
    split = cfg.get("split")
    if isinstance(split, Mapping) and split.get("train_fraction") is not None:
        kwargs["train_fraction"] = split["train_fraction"]
    if cfg.get("resize") is not None:
        resize = cfg["resize"]
        if isinstance(resize, (str, bytes)) or len(resize) != 2:
            raise ValueError(f"resize must be [W, H], got {resize!r}")
        kwargs["size"] = [int(resize[0]), int(resize[1])]

    accepted = set(inspect.signature(gen).parameters)
    unknown = sorted(set(kwargs) - accepted)
    if unknown:
        raise ValueError(f"generator {name!r} does not take parameter(s) {unknown}; accepted: {sorted(accepted)}")
    return gen(**kwargs)
