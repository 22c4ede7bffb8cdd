"""Lazy public names for a package's ``__init__`` (PEP 562 module ``__getattr__``).

``from thermal_twin import load_machine`` imports the defining module on first use, so that
importing one submodule of a package (as every node does) never loads the whole package and
its heavy dependencies, and a ROS-free name never pulls in rclpy.
"""
from __future__ import annotations

import importlib
import sys
from typing import Callable, Mapping, Sequence


def lazy_exports(package: str, modules: Mapping[str, Sequence[str]]
                 ) -> tuple[list[str], Callable[[str], object], Callable[[], list[str]]]:
    """(``__all__``, ``__getattr__``, ``__dir__``) of ``package`` whose public names are
    ``{submodule: [name, ...]}``; a name is defined once, in its submodule."""
    where: dict[str, str] = {}
    for module, names in modules.items():
        for name in names:
            if name in where:
                raise ValueError(f"{package}: public name {name!r} listed under both "
                                 f"{where[name]!r} and {module!r}")
            where[name] = module
    shadowed = sorted(set(where) & set(modules))
    if shadowed:     # importing that submodule binds its name on the package over the exported value
        raise ValueError(f"{package}: public name(s) {shadowed} are also submodule names")

    def __getattr__(name: str) -> object:
        module = where.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f"{package}.{module}"), name)
        setattr(sys.modules[package], name, value)   # later look-ups skip this function
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(where))

    return sorted(where), __getattr__, __dir__
