"""What every command-line stage shares: composing the configuration, the artifact paths, the resolved-config record.

Used by :mod:`lagsplat.cli` (the entry point) and the stage modules
:mod:`lagsplat.stages` and :mod:`lagsplat.stages_report`.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from collections.abc import Sequence
from typing import TYPE_CHECKING

from omegaconf import DictConfig, OmegaConf

if TYPE_CHECKING:
    from lagsplat.artifacts import Artifacts

__all__ = ["find_conf_dir", "compose", "artifacts_of", "apply_variant", "save_stage_config", "plain", "data_kind"]


def find_conf_dir() -> Path:
    """Locate the Hydra ``conf/`` folder.

    Order: ``$LAGSPLAT_CONF``, ``./conf`` in the working directory, then the
    ``conf/`` beside the package (a source checkout / editable install).

    Raises:
        FileNotFoundError: if none has a ``config.yaml``.
    """
    cands = [os.environ.get("LAGSPLAT_CONF"), Path.cwd() / "conf", Path(__file__).resolve().parents[1] / "conf"]
    for c in cands:
        if c and (Path(c) / "config.yaml").exists():
            return Path(c).resolve()
    raise FileNotFoundError("no conf/config.yaml found: run from the project root or set LAGSPLAT_CONF")


def compose(overrides: list[str]) -> DictConfig:
    """Compose the configuration (``conf/config.yaml`` + system + overrides)."""
    from hydra import compose as hcompose
    from hydra import initialize_config_dir

    from lagsplat.config_schema import register_schemas

    register_schemas()

    with initialize_config_dir(config_dir=str(find_conf_dir()), version_base=None):
        return hcompose(config_name="config", overrides=overrides)


def artifacts_of(cfg: DictConfig) -> "Artifacts":
    """The run's artifact paths (:class:`lagsplat.artifacts.Artifacts`): ``${results_dir}/<system>/``,
    the model's under ``variants/<variant>/`` when ``variant`` is set, each overridable as ``artifacts.<name>=PATH``."""
    from lagsplat.artifacts import Artifacts

    return Artifacts.for_run(cfg.results_dir, cfg.system.name, cfg.get("variant"), plain(cfg.get("artifacts") or {}))


#: ``<variant>@seed<k>``: a variant's run with training seed ``k`` (:func:`split_variant`).
SEEDED_VARIANT = re.compile(r"^(?P<name>[^@]+)@seed(?P<seed>\d+)$")


def split_variant(v: str) -> tuple[str, int | None]:
    """``"mass_decoder@seed3"`` -> ``("mass_decoder", 3)``; a name without the suffix -> ``(name, None)``."""
    m = SEEDED_VARIANT.match(str(v))
    return (m["name"], int(m["seed"])) if m else (str(v), None)


def seeded_variants(name: str, seeds: Sequence[int] | None) -> list[str]:
    """The run names of variant ``name`` over ``seeds`` (any sequence of integers, e.g. the configuration's
    ``ablation_seeds``; ``name@seed<k>`` each; ``None``: ``[name]``, the run's own seed)."""
    return [name] if seeds is None else [f"{name}@seed{int(k)}" for k in seeds]


def apply_variant(cfg: DictConfig) -> DictConfig:
    """Merge ``variants[cfg.variant]`` into ``cfg`` (no-op without a variant).

    ``variant=<name>@seed<k>`` merges ``variants[<name>]`` and sets ``seed=k``: the
    variant's Stage 2 on the same frozen chart with another training seed (its
    artifacts under ``variants/<name>@seed<k>/``), for ablations reported as the
    median over seeds (paper §4.1).

    Raises:
        KeyError: naming the unknown variant and the known ones.
    """
    v = cfg.get("variant")
    if not v:
        return cfg
    name, seed = split_variant(v)
    known = cfg.get("variants") or {}
    if name not in known:
        raise KeyError(f"unknown variant {name!r}; known: {sorted(known)} (conf/config.yaml, key variants)")
    out = OmegaConf.merge(cfg, known[name])
    if seed is not None:
        out.seed = seed
    return out


def save_stage_config(cfg: DictConfig, stage: str, a: "Artifacts | None" = None) -> None:
    """Write the resolved configuration of ``stage`` beside its output (:meth:`lagsplat.artifacts.Artifacts.config`
    of ``a``, default the run's :func:`artifacts_of`), atomically."""
    from lagsplat.io.atomic import atomic_write

    with atomic_write((a or artifacts_of(cfg)).config(stage)) as tmp:
        tmp.write_text(OmegaConf.to_yaml(cfg, resolve=True))


def plain(node) -> dict:
    """A configuration node as a plain, resolved ``dict`` (a mapping that is already plain is copied)."""
    return OmegaConf.to_container(node, resolve=True) if isinstance(node, DictConfig) else dict(node)


def data_kind(system: DictConfig) -> str:
    """What a system's clip is: ``system.data`` when set (``real`` | ``surrogate``), else ``synthetic`` for a
    procedural source (``source.synth``) and ``real`` for a recording."""
    if system.get("data"):
        return str(system.data)
    sources = list(system.get("sources") or []) or [system.get("source") or {}]
    return "synthetic" if all(src.get("synth") for src in sources) else "real"
