"""The lazy packages (aeid_struct/lazy.py): a name's module is imported on first use, kept in
the package, modules imported together where asked, unknown names refused by name."""

import subprocess
import sys
import textwrap

import pytest

from aeid_struct.lazy import attach


def _package(tmp_path):
    root = tmp_path / "pkg"
    root.mkdir()
    (root / "__init__.py").write_text(textwrap.dedent('''
        from aeid_struct.lazy import attach
        SEEN = []
        __all__ = ["A", "B", "C"]
        __getattr__, __dir__ = attach(__name__, {"A": "a", "B": "b", "C": "c"},
                                      together=("a", "b"))
    '''))
    for name in "abc":
        (root / f"{name}.py").write_text(
            f"from pkg import SEEN\nSEEN.append({name!r})\n{name.upper()} = {name!r}\n")
    return tmp_path


def test_a_name_imports_its_module_once_and_together_with_its_siblings(tmp_path):
    script = ("import sys, pkg\n"
              "print(sorted(m for m in sys.modules if m.startswith('pkg.')))\n"
              "print(pkg.A, pkg.SEEN)\n"
              "print('A' in vars(pkg), 'C' in vars(pkg), 'C' in dir(pkg))\n"
              "print(pkg.C, pkg.SEEN)\n")
    out = subprocess.run([sys.executable, "-c", script], cwd=_package(tmp_path),
                         capture_output=True, text=True, check=True).stdout.splitlines()
    assert out == ["[]", "a ['a', 'b']", "True False True", "c ['a', 'b', 'c']"]


def test_an_unknown_name_is_refused_by_name():
    getattr_, _ = attach("aeid_struct.structures", {})
    with pytest.raises(AttributeError, match="'aeid_struct.structures' has no attribute 'Nope'"):
        getattr_("Nope")


def test_the_library_packages_name_their_lazy_names():
    import aeid_struct.refinement as refinement
    import aeid_struct.structures as structures

    assert {"CCF", "Structure", "ccf_matrices"} <= set(dir(structures))
    assert refinement.refine_record.__module__ == "aeid_struct.refinement.record"


def test_a_name_that_is_gone_warns_with_its_replacement():
    import aeid_struct.refinement as refinement
    from aeid_struct.estimates import Estimate

    with pytest.warns(DeprecationWarning, match="refine_record and refine_separable return an "
                                                "Estimate"):
        assert refinement.RecordFit is Estimate
    with pytest.warns(DeprecationWarning):       # every read warns, not only the first
        assert refinement.RecordFit is Estimate
