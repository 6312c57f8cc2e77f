"""Packages that import some of their modules on first use of a name (PEP 562): the one
``__getattr__`` of ``structures``, ``simulation``, ``refinement`` and ``identification``, which
import their torch-free modules with the package and the others when a name of theirs is first
read, so that the ONNX runner, the separable head and an estimate's physical parameters run
where torch is not installed. Layer: the foundation (it imports nothing of the library).
"""

from __future__ import annotations

import sys
import warnings
from importlib import import_module

__all__ = ["attach"]


def attach(package: str, table: dict[str, str], together: tuple[str, ...] = (),
           deprecated: dict[str, tuple[str, str, str]] | None = None):
    """The module-level ``__getattr__`` and ``__dir__`` of a package whose names ``table`` maps
    to the modules that define them.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    table : dict name -> module
        A public name and the package's module (relative, e.g. ``"canonical"``) that defines it.
    together : tuple of str
        Modules imported together whenever one of them is (a registry filled on import must
        know every entry whichever name came first).
    deprecated : dict old name -> (module, name, message), optional
        Names that are gone: reading one warns (DeprecationWarning) with ``message`` and
        returns ``module.name``, its replacement (not kept, so that every read warns).

    Returns
    -------
    (callable, callable)
        ``__getattr__(name)``: imports the name's module, keeps the name in the package and
        returns it (AttributeError for a name not in ``table``); ``__dir__()``.
    """
    def __getattr__(name: str):
        if deprecated and name in deprecated:
            module, new, message = deprecated[name]
            warnings.warn(message, DeprecationWarning, stacklevel=2)
            return getattr(import_module(module), new)
        module = table.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        for other in together if module in together else ():
            import_module(f".{other}", package)
        value = getattr(import_module(f".{module}", package), name)
        setattr(sys.modules[package], name, value)     # later reads skip __getattr__
        return value

    def __dir__() -> list[str]:
        namespace = vars(sys.modules[package])
        return sorted(set(namespace) | set(namespace.get("__all__", ())))

    return __getattr__, __dir__
