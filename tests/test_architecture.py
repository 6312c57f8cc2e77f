"""The architecture rules of issue 13, checked on the source (docs/architecture.md, "Layers and
contracts"): the import contracts of pyproject.toml (import-linter), no module reaching into
another module's ``_private`` names, size limits of modules, classes and functions, and no citation
of files outside the repository. Each failure lists every offender, so one run shows all the work.

tests/ are exempt from these rules: tests may reach into private helpers to pin them.
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("aeid_struct", "symbolic")

MODULE_LINES = 500      # a module: every line of the file
CLASS_LINES = 250       # a class: from its first decorator to its last line
FUNCTION_LINES = 80     # a function: from its first decorator to its last line, less its docstring

# The order of rule 1 (highest first), as the layers contract must state it; ``loading`` (the one
# ``load`` of every identifier kind) sits above the kinds it reads
LAYERS = [
    "cli", "studies", "fleet", "loading", "online", "evaluation", "baselines", "training",
    "generic", "multi", "identification", "refinement", "estimates", "encoder", "simulation",
    "structures",
    "records | metrics | lazy | threads",
]


def _sources() -> dict[str, Path]:
    """Dotted module name -> file, for every module of the library and of ``symbolic``."""
    modules = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            modules[".".join(parts)] = path
    return modules


SOURCES = _sources()


def _where(path: Path, line: int | None = None) -> str:
    where = path.relative_to(ROOT).as_posix() if path.is_relative_to(ROOT) else str(path)
    return where if line is None else f"{where}:{line}"


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


# ---------------------------------------------------------------------------------------------
# import-linter contracts
# ---------------------------------------------------------------------------------------------

def test_import_contracts_are_kept():
    """``lint-imports`` with the contracts of pyproject.toml: every contract kept."""
    # The CLI of import-linter, run by this interpreter, from the repository root: it puts the
    # working directory first on sys.path, so the checkout under test is the one analysed (not an
    # installed copy). No cache: the answer depends on the files alone.
    run = subprocess.run(
        [sys.executable, "-c", "from importlinter.cli import lint_imports_command; "
         "lint_imports_command()", "--no-cache", "--no-logo"],
        cwd=ROOT, capture_output=True, text=True, timeout=300,
    )
    report = run.stdout + run.stderr
    assert "broken" in report, f"lint-imports gave no report (exit {run.returncode}):\n{report}"
    assert run.returncode == 0, f"import contracts broken:\n{report}"
    assert re.search(r"Contracts: \d+ kept, 0 broken", report), report


def test_layers_contract_states_rule_1():
    """The layers contract is the one of issue 13 rule 1, exhaustive over the sub-packages, so a
    new package must be given its place (a test that pins the contract, so that weakening it is a
    visible change)."""
    from importlinter.api import read_configuration

    config = read_configuration(str(ROOT / "pyproject.toml"))
    assert sorted(config["session_options"]["root_packages"]) == sorted(PACKAGES)
    layers = [c for c in config["contracts_options"] if c["type"] == "layers"]
    assert len(layers) == 1, f"expected one layers contract; got {len(layers)}"
    (contract,) = layers
    assert contract["containers"] == ["aeid_struct"]
    assert contract["layers"] == LAYERS
    assert contract.get("exhaustive") in (True, "true", "True")
    assert not contract.get("ignore_imports"), (
        f"the layers contract ignores imports: {contract['ignore_imports']}")


# ---------------------------------------------------------------------------------------------
# _private names
# ---------------------------------------------------------------------------------------------

def _resolve(importer: str, is_package: bool, module: str | None, level: int) -> str:
    """The absolute name of ``from <level dots><module> import ...`` written in ``importer``."""
    if level == 0:
        return module or ""
    base = importer.split(".")
    if not is_package:
        base = base[:-1]
    base = base[: len(base) - (level - 1)]
    return ".".join(base + ([module] if module else []))


def _inside(importer: str, package: str) -> bool:
    return importer == package or importer.startswith(package + ".")


def _private_uses(name: str, path: Path) -> list[str]:
    """Every place where module ``name`` uses a ``_private`` name of another project module.

    ``from m import _x`` and ``m._x`` (``m`` a name bound to a project module by an import) are
    uses, unless ``m._x`` is itself a private *module* and the user is package ``m`` or one of its
    direct members (a package's ``__init__`` and its modules may import its private modules, as
    ``aeid_struct`` imports ``_compat``).
    """
    tree = ast.parse(path.read_text(encoding="utf-8"))
    is_package = path.name == "__init__.py"
    found = []

    def check(target: str, line: int) -> None:
        owner, _, attr = target.rpartition(".")
        if not _private(attr) or owner not in SOURCES:
            return
        if target in SOURCES and owner in (name, name.rpartition(".")[0]):
            return                      # a private module of the importer's own package
        found.append(f"{_where(path, line)}: {target}")

    bound: dict[str, str] = {}          # local name -> project module it names
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                parts = alias.name.split(".")
                for i in range(1, len(parts)):
                    check(".".join(parts[: i + 1]), node.lineno)
                if alias.asname:
                    bound[alias.asname] = alias.name
                else:
                    bound[parts[0]] = parts[0]
        elif isinstance(node, ast.ImportFrom):
            source = _resolve(name, is_package, node.module, node.level)
            for alias in node.names:
                target = f"{source}.{alias.name}"
                check(target, node.lineno)
                if target in SOURCES:
                    bound[alias.asname or alias.name] = target
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and _private(node.attr):
            chain, value = [node.attr], node.value
            while isinstance(value, ast.Attribute):
                chain.append(value.attr)
                value = value.value
            if isinstance(value, ast.Name) and value.id in bound:
                # the longest prefix of the chain that is a project module owns the last name
                dotted = ".".join([bound[value.id], *reversed(chain)])
                if dotted.rpartition(".")[0] in SOURCES:
                    check(dotted, node.lineno)
    return found


def test_no_module_uses_another_modules_private_names():
    """Issue 13 rule 2: a helper shared by two modules gets a public name in a module of its own;
    ``from x import _y`` and ``x._y`` across modules are not allowed (tests are exempt)."""
    offenders = [use for name, path in SOURCES.items() for use in _private_uses(name, path)]
    assert not offenders, (
        f"{len(offenders)} uses of another module's private name:\n" + "\n".join(offenders))


def _old_paths() -> dict[str, str]:
    from aeid_struct import _compat

    return {f"aeid_struct.{old}": f"aeid_struct.{new}" for old, new in _compat.ALIASES.items()}


def _imports(name: str, path: Path) -> list[tuple[str, int]]:
    """(absolute target, line) of every import in a module, a ``from`` import's names included."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    is_package = path.name == "__init__.py"
    targets = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets += [(alias.name, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            source = _resolve(name, is_package, node.module, node.level)
            targets.append((source, node.lineno))
            targets += [(f"{source}.{alias.name}", node.lineno) for alias in node.names]
    return targets


def test_library_uses_neither_old_paths_nor_the_root_namespace():
    """The old flat paths (``aeid_struct.decoder``, ...) are aliases for users; the library imports
    the new packages. Nor does the library import the root namespace (``import aeid_struct as
    ae``): its lazy table hides which package a name comes from (studies and the CLI may)."""
    old = _old_paths()
    offenders = []
    for name, path in SOURCES.items():
        if name == "aeid_struct._compat":
            continue
        app = _inside(name, "aeid_struct.studies") or _inside(name, "aeid_struct.cli")
        for target, line in _imports(name, path):
            hit = next((o for o in old if _inside(target, o)), None)
            if hit is not None:
                offenders.append(f"{_where(path, line)}: {target} (old path; use {old[hit]}'s "
                                 "package)")
            elif target == "aeid_struct" and not app and name != "aeid_struct":
                offenders.append(f"{_where(path, line)}: imports the root namespace aeid_struct")
    assert not offenders, f"{len(offenders)} imports to change:\n" + "\n".join(offenders)


# ---------------------------------------------------------------------------------------------
# sizes
# ---------------------------------------------------------------------------------------------

def _definitions():
    """(kind, where, name, lines) of every class and function (methods and nested ones too)."""
    for path in SOURCES.values():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if not isinstance(node, (ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            start = min([node.lineno] + [d.lineno for d in node.decorator_list])
            lines = node.end_lineno - start + 1
            if isinstance(node, ast.ClassDef):
                yield "class", _where(path, node.lineno), node.name, lines
                continue
            first = node.body[0]
            if (isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant)
                    and isinstance(first.value.value, str)):
                # a numpydoc docstring grows with the arguments it documents: it does not count
                lines -= first.end_lineno - first.lineno + 1
            yield "function", _where(path, node.lineno), node.name, lines


def _report(offenders: list[tuple[int, str]], what: str, limit: int) -> str:
    rows = "\n".join(f"{lines:5d}  {where}" for lines, where in sorted(offenders, reverse=True))
    return f"{len(offenders)} {what} over {limit} lines:\n{rows}"


def test_modules_are_at_most_500_lines():
    offenders = []
    for path in SOURCES.values():
        lines = len(path.read_text(encoding="utf-8").splitlines())
        if lines > MODULE_LINES:
            offenders.append((lines, _where(path)))
    assert not offenders, _report(offenders, "modules", MODULE_LINES)


def test_classes_are_at_most_250_lines():
    offenders = [(lines, f"{where} {name}") for kind, where, name, lines in _definitions()
                 if kind == "class" and lines > CLASS_LINES]
    assert not offenders, _report(offenders, "classes", CLASS_LINES)


def test_functions_are_at_most_80_lines():
    offenders = [(lines, f"{where} {name}") for kind, where, name, lines in _definitions()
                 if kind == "function" and lines > FUNCTION_LINES]
    assert not offenders, _report(offenders, "functions (docstring excluded)", FUNCTION_LINES)


# ---------------------------------------------------------------------------------------------
# citations
# ---------------------------------------------------------------------------------------------

# DESIGN.md is gone (the design is docs/architecture.md); ../shared and absolute paths of a build
# machine are outside the repository, so a reader of the package cannot follow them.
OUTSIDE = re.compile(r"DESIGN\.md|\.\./shared|(?<![\w.])/work/|\bshared/paper\b")
TEXT = {".py", ".md", ".txt", ".json", ".toml", ".cfg", ".rst"}


def test_sources_cite_only_files_in_the_repository():
    offenders = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*")):
            if path.suffix not in TEXT or "__pycache__" in path.parts:
                continue
            for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                for match in OUTSIDE.finditer(line):
                    offenders.append(f"{_where(path, number)}: {match.group()}")
    assert not offenders, (
        f"{len(offenders)} citations of files outside the repository (cite docs/architecture.md):"
        "\n" + "\n".join(offenders))


def test_the_checks_see_the_whole_package():
    """The checks above are only as good as the module list they walk: it must hold every
    sub-package of the layers and symbolic's modules."""
    for layer in LAYERS:
        for package in layer.split(" | "):
            assert f"aeid_struct.{package}" in SOURCES, f"aeid_struct.{package} not found"
    assert {"symbolic.leg", "symbolic.named"} <= set(SOURCES)


@pytest.mark.parametrize("name, source, expected", [
    ("aeid_struct.identification.fake", "from aeid_struct.simulation.foh import _check_dt\n",
     ["aeid_struct.simulation.foh._check_dt"]),
    ("aeid_struct.identification.fake", "from ..simulation import foh\nfoh._simulate(1)\n",
     ["aeid_struct.simulation.foh._simulate"]),
    ("aeid_struct.identification.fake", "import aeid_struct.simulation.foh as f\nf._discretise\n",
     ["aeid_struct.simulation.foh._discretise"]),
    ("aeid_struct.identification.fake", "import aeid_struct\naeid_struct.simulation.foh._F\n",
     ["aeid_struct.simulation.foh._F"]),
    ("aeid_struct.identification.fake", "from aeid_struct import _compat\n",
     ["aeid_struct._compat"]),
    ("aeid_struct.identification.fake", "from aeid_struct.simulation import simulate\n"
     "simulate._cache\n", []),
    ("aeid_struct.identification.fake", "import torch\ntorch._C\n", []),
    ("aeid_struct", "from . import _compat\n_compat.install()\n", []),
    ("aeid_struct.records", "from aeid_struct import _compat\n", []),
])
def test_private_name_check_finds_what_it_should(tmp_path, name, source, expected):
    """The private-name check on hand-written modules: the uses it must catch, and what it must
    leave alone (a private module of the importer's own package, attributes of objects and of
    external modules). ``name`` places the module in the package."""
    file = tmp_path / ("__init__.py" if name == "aeid_struct" else "fake.py")
    file.write_text(source, encoding="utf-8")
    uses = _private_uses(name, file)
    assert [use.split(": ", 1)[1] for use in uses] == expected


def _module_graph() -> dict[str, set[str]]:
    """Module -> the modules it imports, every import counted (inside functions too, and
    ``import_module("...")`` with a literal name); packages' ``__init__`` files left out (they
    re-export, and an edge through one is an edge to what it re-exports)."""
    modules = {n for n, p in SOURCES.items() if p.name != "__init__.py"}
    graph = {}
    for name in modules:
        targets = {t for t, _ in _imports(name, SOURCES[name])}
        tree = ast.parse(SOURCES[name].read_text(encoding="utf-8"))
        targets |= {node.args[0].value for node in ast.walk(tree)
                    if isinstance(node, ast.Call) and node.args
                    and getattr(node.func, "id", getattr(node.func, "attr", None)) ==
                    "import_module" and isinstance(node.args[0], ast.Constant)}
        graph[name] = {t for t in targets if t in modules and t != name}
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while not component or component[-1] != v:
                component.append(stack.pop())
                on.discard(component[-1])
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_import_cycle_between_modules():
    # not even between two files of one package, nor through an import inside a function: two
    # files that import each other are one concept split badly (STYLE.md, rule 14)
    cycles = _cycles(_module_graph())
    assert not cycles, "import cycles: " + "; ".join(" <-> ".join(c) for c in cycles)


def test_the_cycle_check_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []
