"""Package names imported from their submodules on first use (PEP 562 module ``__getattr__``).

A package whose ``__init__`` imports every submodule makes each of its importers pay for all of them (SciPy,
OpenCV, torchdiffeq); :func:`lazy_exports` gives the package a ``__getattr__`` and a ``__dir__`` that import
a name's submodule when the name is first read, then keep the value in the package.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["lazy_exports"]


def lazy_exports(package: str, exports: Mapping[str, str]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """``(__getattr__, __dir__)`` for ``package``, whose public ``name`` lives in ``package.<exports[name]>``.

    Args:
        package: the package's ``__name__``.
        exports: public name -> submodule (relative to ``package``) that defines it.

    Returns:
        The two module-level functions; assign them in the package's ``__init__``.

    The returned ``__getattr__`` raises ``AttributeError`` for a name ``exports`` does not hold.
    """

    def __getattr__(name: str) -> Any:
        mod = exports.get(name)
        if mod is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f"{package}.{mod}"), name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(exports))

    return __getattr__, __dir__
