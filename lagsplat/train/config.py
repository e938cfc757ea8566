"""Building the stage settings dataclasses from (Hydra) mappings."""

from __future__ import annotations

from dataclasses import fields
from typing import Any, Mapping, TypeVar

__all__ = ["dataclass_from_mapping"]

T = TypeVar("T")


def dataclass_from_mapping(cls: type[T], m: Mapping[str, Any], group: str) -> T:
    """Instantiate the settings dataclass ``cls`` from ``m``; lists become tuples.

    Raises:
        KeyError: naming the config ``group`` and every unknown key.
    """
    known = {f.name for f in fields(cls)}
    unknown = set(m) - known
    if unknown:
        raise KeyError(f"unknown {group} settings: {sorted(unknown)}")
    return cls(**{k: (tuple(v) if type(v).__name__ in ("ListConfig", "list") else v) for k, v in m.items()})
