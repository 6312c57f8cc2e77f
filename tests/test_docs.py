"""The documentation: the site builds from the docstrings with warnings as errors, and the
docstrings are numpydoc (issue 13 rule 4): no Google-style sections, and every public function,
class and method documents its parameters (and what it returns) in numpydoc sections.

Each failure lists every offender by file, so that each package's owner finds their share.
"""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import griffe  # installed with mkdocstrings-python (the dev extra)
import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("aeid_struct", "symbolic")


@pytest.mark.slow
def test_site_builds_without_warnings(tmp_path):
    """``mkdocs build --strict`` (mkdocs.yml): a docstring that does not parse as numpydoc, a
    broken cross-reference or link, or a README section the site splices in that is gone, fails."""
    run = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file",
         str(ROOT / "mkdocs.yml"), "--site-dir", str(tmp_path / "site")],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
        # the theme's end-of-life banner is not a warning of this build
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1", "NO_COLOR": "1"},
    )
    log = run.stdout + run.stderr
    warnings = [line for line in log.splitlines() if line.startswith(("WARNING", "ERROR"))]
    by_file = defaultdict(list)
    for line in warnings:
        # "WARNING -  griffe: aeid_struct/x.py:12: ..." or
        # "WARNING -  mkdocs_autorefs: api/x.md: ..."
        match = re.search(r"-\s+(?:[\w.]+: )?([\w./-]+\.(?:py|md))", line)
        by_file[match.group(1) if match else "(other)"].append(line)
    report = "\n".join(f"{file} ({len(lines)}):\n  " + "\n  ".join(lines)
                       for file, lines in sorted(by_file.items()))
    assert run.returncode == 0 and not warnings, (
        f"mkdocs build --strict: exit {run.returncode}, {len(warnings)} warnings\n{report}\n"
        + ("" if warnings else log[-3000:]))
    assert (tmp_path / "site" / "api" / "identification" / "index.html").is_file()


# ---------------------------------------------------------------------------------------------
# docstring style
# ---------------------------------------------------------------------------------------------

GOOGLE = re.compile(r"^\s*(Args|Arguments|Keyword Args|Returns|Yields|Raises|Attributes|"
                    r"Example|Examples|Note|Notes|Warns|Warnings|See Also|Parameters):\s*$")


def _docstrings(tree: ast.Module):
    """(line of the docstring, docstring) of the module and of every class and function."""
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if (body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant)
                    and isinstance(body[0].value.value, str)):
                yield body[0].lineno, body[0].value.value


def test_docstrings_have_no_google_sections():
    """``Args:`` / ``Returns:`` / ``Attributes:`` headers are Google style; numpydoc writes
    ``Parameters`` underlined with dashes (the site renders Google sections as plain text, so the
    build alone does not catch them)."""
    offenders = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"))
            for line, text in _docstrings(tree):
                for offset, row in enumerate(text.splitlines()):
                    if GOOGLE.match(row):
                        where = f"{path.relative_to(ROOT).as_posix()}:{line + offset}"
                        offenders.append(f"{where}: {row.strip()}")
    assert not offenders, (
        f"{len(offenders)} Google-style section headers (use numpydoc sections):\n"
        + "\n".join(offenders))


# ---------------------------------------------------------------------------------------------
# the public API is documented
# ---------------------------------------------------------------------------------------------

def _load():
    # static analysis of the checkout's sources: nothing is imported or executed
    return [griffe.load(package, search_paths=[str(ROOT)], docstring_parser="numpy")
            for package in PACKAGES]


def _public(module):
    """(name, object) of a module's public names: its ``__all__``, or else its own public
    definitions (imported names excluded)."""
    names = module.exports
    if names is None:
        names = [n for n, m in module.members.items() if not n.startswith("_") and not m.is_alias]
    for name in names:
        name = name if isinstance(name, str) else name.name
        obj = module[name]
        yield name, obj.final_target if obj.is_alias else obj


def _api():
    """(dotted path, object) of every public function and class: each package's exports (its
    modules' public names where its ``__init__`` exports nothing), with the public methods of
    its classes."""
    aeid, symbolic = _load()
    modules = [m for name, m in aeid.modules.items() if name not in ("pretrained", "_compat")]
    modules += list(symbolic.modules.values())
    for module in modules:
        items = list(_public(module))
        if module.modules and module.exports is None:
            items = [(f"{sub.name}.{name}", obj) for sub in module.modules.values()
                     if not sub.name.startswith("_") for name, obj in _public(sub)]
        for name, obj in items:
            if obj.kind.value not in ("function", "class"):
                continue
            yield f"{module.path}.{name}", obj
            if obj.kind.value == "class":
                for method_name, method in obj.members.items():
                    if (not method_name.startswith("_") and not method.is_alias
                            and method.kind.value == "function"
                            and "property" not in method.labels):
                        yield f"{module.path}.{name}.{method_name}", method


def _problems(obj) -> list[str]:
    if obj.kind.value == "class":
        bases = " ".join(str(b) for b in obj.bases)
        if re.search(r"Error|Exception|Warning|Exit", bases):
            return [] if obj.docstring else ["no docstring"]   # an exception: what it means
        init = obj.all_members.get("__init__")
        parameters = init.parameters if init is not None else []
    else:
        parameters = obj.parameters
    names = [p.name for p in parameters if p.name not in ("self", "cls") and not
             p.name.startswith("_")]
    if obj.docstring is None:
        return ["no docstring"]
    sections = obj.docstring.parse("numpy", warnings=False)
    kinds = {s.kind.value for s in sections}
    # a class may document its constructor's arguments as Attributes (a dataclass's fields)
    documented = {item.name.lstrip("*") for s in sections
                  if s.kind.value in ("parameters", "other parameters", "attributes")
                  for item in s.value}
    problems = []
    missing = [name for name in names if name not in documented]
    if missing:
        problems.append(f"parameters not in a numpydoc section: {', '.join(missing)}")
    if (obj.kind.value == "function" and obj.returns is not None
            and str(obj.returns) != "None" and not kinds & {"returns", "yields"}):
        problems.append(f"returns {obj.returns} but has no Returns section")
    return problems


def test_public_api_documents_its_parameters():
    """Every public function, class and method documents each parameter in a numpydoc
    ``Parameters`` section (a class: ``Parameters`` or ``Attributes``), and a function that
    returns something has a ``Returns`` section."""
    api = list(_api())
    assert len(api) > 50, f"found only {len(api)} public objects: is the package walk broken?"
    by_file = defaultdict(list)
    for path, obj in api:
        for problem in _problems(obj):
            by_file[obj.relative_filepath.as_posix()].append(f"{obj.lineno}: {path}: {problem}")
    count = sum(map(len, by_file.values()))
    report = "\n".join(f"{file} ({len(rows)}):\n  " + "\n  ".join(rows)
                       for file, rows in sorted(by_file.items()))
    assert not by_file, (
        f"{count} undocumented parts of the public API ({len(api)} objects):\n{report}")
