"""A library of models: built-ins made on first use, and models a user registers (by name, a later
registration replacing an earlier one). One registry for the CAD object models and one for the
structure models."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Generic, TypeVar

M = TypeVar("M")


class ModelRegistry(Generic[M]):
    def __init__(self, build_builtins: Callable[[], dict[str, M]]):
        self._builtins = functools.cache(build_builtins)  # meshes take a while: build once, when asked
        self._user: dict[str, M] = {}

    def builtin(self, name: str) -> M:
        return self._builtins()[name]

    def all(self) -> dict[str, M]:
        """Every model by name, the registered ones after (and over) the built-ins."""
        return {**self._builtins(), **self._user}

    def add(self, name: str, model: M) -> None:
        self._user[name] = model

    def remove(self, name: str) -> None:
        """Forget a registered model (no-op if unknown)."""
        self._user.pop(name, None)
