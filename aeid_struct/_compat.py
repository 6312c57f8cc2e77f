"""Old module paths of the flat layout, kept working after the redesign.

Before the library was split into sub-packages, ``aeid_struct.decoder``, ``aeid_struct.refine``,
``aeid_struct.export`` and the like were modules of their own. Users' code and notebooks import
them; so that nothing breaks, each old path is an alias of the module that now holds the code:
``import aeid_struct.refine`` returns ``aeid_struct.refinement.nlp`` itself (one module object
under two names, so monkeypatching either patches both). Old paths that became sub-packages of
the same name (``structures``, ``encoder``, ``training``, ``baselines``, ``online``, ``cli``)
need no alias: the package re-exports the old module's public names. The old module
``aeid_struct.identify`` has no alias: ``aeid_struct.identify`` is the one-call function
(``aeid_struct.generic.identify``) now; its code lives in ``aeid_struct.identification``.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys

#: old module path (under ``aeid_struct``) -> the package (its public names) or module that holds
#: its code now
ALIASES = {
    "decoder": "simulation",
    "data": "training",
    "refine": "refinement",
    "scorecard": "evaluation.scorecard",
    "plots": "evaluation.plots",
    "export": "online.export",
    "casadi_torch": "structures.casadi_torch",
    "maps": "structures.maps",
    "study": "studies.leg_paper",
    "knowledge": "studies.knowledge",
    "bench": "studies.bench",
    "bench_online": "studies.bench_online",
}


class _AliasLoader(importlib.abc.Loader):
    """Loads an old path as the module that now holds its code (imported on first use)."""

    def __init__(self, target: str) -> None:
        self.target = target

    def create_module(self, spec):
        return importlib.import_module(self.target)

    def exec_module(self, module) -> None:
        """The target module ran when it was imported; nothing more to do."""


class AliasFinder(importlib.abc.MetaPathFinder):
    """Finds ``aeid_struct.<old>`` for the old paths in ``ALIASES``, and nothing else."""

    def find_spec(self, fullname: str, path=None, target=None):
        package, _, name = fullname.rpartition(".")
        if package != "aeid_struct" or name not in ALIASES:
            return None
        loader = _AliasLoader(f"aeid_struct.{ALIASES[name]}")
        return importlib.machinery.ModuleSpec(fullname, loader)


def install() -> None:
    """Put the finder first on ``sys.meta_path``, once: it answers only for the old paths, and
    must win over path-based finders that could see a stale file of the old layout (an editable
    install of an older checkout, a leftover ``.py``)."""
    if not any(isinstance(f, AliasFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, AliasFinder())
