"""Typed configuration (lagsplat.config_schema): every system validates, a bad value stops at start-up
with one line naming key and value, and the YAML repeats no default of the dataclasses with another value."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import yaml

from lagsplat.cli import compose, main
from lagsplat.config_schema import NESTED, SCHEMAS, ConfigError, validate_config

ROOT = Path(__file__).resolve().parents[1]
SYSTEMS = sorted(p.stem for p in (ROOT / "conf" / "system").glob("*.yaml"))


@pytest.mark.parametrize("system", SYSTEMS)
def test_every_system_composes_and_validates(system: str) -> None:
    validate_config(compose([f"system={system}"]))


@pytest.mark.parametrize(
    "override, needle",
    [
        ("stage1.steps=-1", "stage1.steps=-1: must be >= 1"),
        ("device=gpu", "device='gpu': must be one of"),
        ("stage2.mass=heavy", "stage2.mass='heavy': must be one of"),
        ("system.d=0", "system.d=0: must be >= 1"),
        ("stage1.n_gaussians=many", "stage1.n_gaussians='many': must be an integer"),
        ("system.split.train_fraction=0", "system.split.train_fraction=0: must be in (0, 1]"),
        ("view.image_format=gif", "view.image_format='gif': must be one of"),
        ("stage1.nope=1", "stage1.nope"),
        ("+stage2.nope=1", "stage2.nope: unknown key"),
    ],
)
def test_a_bad_value_stops_at_start_up_naming_key_and_value(override: str, needle: str, tmp_path: Path, capsys) -> None:
    assert main(["stage1", "system=toy", f"results_dir={tmp_path}", override]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "configuration error" in err[0] and needle in err[0], err
    assert not any(tmp_path.iterdir())  # nothing ran


def test_validation_catches_a_bad_source_entry() -> None:
    cfg = compose(["system=two_carts"])
    from omegaconf import OmegaConf

    tree = OmegaConf.to_container(cfg, resolve=True)
    tree["system"]["source"]["fps"] = -30.0
    with pytest.raises(ConfigError, match=r"system.source.fps=-30.0: must be > 0"):
        validate_config(tree)


def _defaults(cls) -> dict:
    out = {}
    for f in dataclasses.fields(cls):
        if f.default is not dataclasses.MISSING:
            out[f.name] = list(f.default) if isinstance(f.default, tuple) else f.default
    return out


def test_the_yaml_repeats_no_default_with_another_value() -> None:
    """One source of defaults: conf/config.yaml may spell a default out, but only with the dataclass's value."""
    base = yaml.safe_load((ROOT / "conf" / "config.yaml").read_text())
    groups = dict(SCHEMAS)
    groups.update(NESTED)
    diffs = []
    for name, cls in groups.items():
        node = base
        for part in name.split("."):
            node = (node or {}).get(part)
        if not isinstance(node, dict):
            continue
        for k, v in _defaults(cls).items():
            if k in node and not isinstance(node[k], dict) and node[k] != v:
                diffs.append(f"{name}.{k}: YAML {node[k]!r} vs {cls.__name__} {v!r}")
    assert not diffs, diffs
