"""A stage package whose names are imported on first use (PEP 562): ``import train.cli`` or a spawned
DataLoader worker's ``import dataset.torch_dataset`` does not pay for every module of the package
(PyTorch's 1-2 s, the build's feature extractors), while ``from train import fit`` and ``train.fit(...)``
work as with a package that imports them all."""

from __future__ import annotations

import importlib
import sys
import types


class LazyPackage(types.ModuleType):
    """A package module with ``_exports`` (name -> its module in the package), each imported on first
    use. A name that is also its module's name (``train.fit`` the function, in ``train/fit.py``) stays
    the name: the import system names a submodule on its package once it has loaded, which would hide it."""

    _exports: dict[str, str]

    def __getattr__(self, name: str) -> object:
        module = self._exports.get(name)
        if module is None:
            raise AttributeError(f"module {self.__name__!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f"{self.__name__}.{module}"), name)
        self.__dict__[name] = value
        return value

    def __dir__(self) -> list[str]:
        return sorted(set(self.__dict__) | set(self._exports))

    def __setattr__(self, name: str, value: object) -> None:
        if self._exports.get(name) != name or not isinstance(value, types.ModuleType):
            super().__setattr__(name, value)


def lazy_package(name: str, exports: dict[str, str]) -> list[str]:
    """Makes the package ``name`` (its ``__init__`` calling this) a ``LazyPackage`` offering ``exports``;
    returns its ``__all__``."""
    package = sys.modules[name]
    package.__dict__["_exports"] = exports
    package.__class__ = LazyPackage
    return sorted(exports)
