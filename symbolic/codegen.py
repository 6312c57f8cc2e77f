"""C code from CasADi Functions: write them into one C file, compile it, load it back.

``casadi.CodeGenerator`` writes every Function into one self-contained C file (CasADi's runtime
inlined), with the Functions' names and their input and output names as symbols;
:func:`compile_c` builds a shared library with the system C compiler and loads each Function
again with ``casadi.external``. ``symbolic.leg.generate_c`` and ``symbolic.leg.compile_c`` apply
these to the leg's maps and inverses.
"""

from __future__ import annotations

import pathlib
import shutil
import subprocess
from collections.abc import Iterable

import casadi

__all__ = ["compile_c", "generate_c"]


def generate_c(
    directory: str | pathlib.Path, functions: Iterable[casadi.Function], *, name: str
) -> pathlib.Path:
    """Write ``functions`` into one C file ``directory / f"{name}.c"``.

    Parameters
    ----------
    directory : str or pathlib.Path
        Where to write (created if missing).
    functions : iterable of casadi.Function
        The Functions to generate, each under its own name.
    name : str
        The file's stem, a C identifier.

    Returns
    -------
    pathlib.Path
        The C file, self-contained (CasADi's runtime inlined), with the functions' names and
        their input/output names as symbols.

    Raises
    ------
    ValueError
        If ``name`` is not a C identifier or ``directory`` is not a folder path.
    """
    if not isinstance(name, str) or not name.isidentifier():
        raise ValueError(f"name must be a C identifier (the file stem); got {name!r}")
    if not isinstance(directory, (str, pathlib.PurePath)) or not str(directory):
        raise ValueError(f"directory must be a folder path (str or Path); got {directory!r}")
    directory = pathlib.Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    generator = casadi.CodeGenerator(f"{name}.c")
    for function in functions:
        generator.add(function)
    return pathlib.Path(generator.generate(str(directory) + "/"))


def compile_c(
    c_file: str | pathlib.Path, names: Iterable[str], *, compiler: str | None = None
) -> dict[str, casadi.Function]:
    """Compile a file from :func:`generate_c` to a shared library and load its functions.

    Parameters
    ----------
    c_file : str or pathlib.Path
        The C file; the library is written next to it with the suffix ``.so``.
    names : iterable of str
        The Functions to load from the library.
    compiler : str, optional
        The C compiler's path; by default ``gcc``, else ``cc``, from ``PATH``.

    Returns
    -------
    dict[str, casadi.Function]
        name -> ``casadi.external`` Function, with the same input and output names as the
        original.

    Raises
    ------
    FileNotFoundError
        If ``c_file`` is not an existing file.
    RuntimeError
        If no C compiler is found, or compilation fails (the message carries the compiler's
        output).
    """
    c_file = pathlib.Path(c_file)
    if not c_file.is_file():
        raise FileNotFoundError(f"c_file must be an existing C file; got {c_file}")
    compiler = compiler or shutil.which("gcc") or shutil.which("cc")
    if compiler is None:
        raise RuntimeError("compile_c needs a C compiler: neither gcc nor cc is on PATH")
    library = c_file.with_suffix(".so")
    command = [compiler, "-shared", "-fPIC", "-O2", str(c_file), "-o", str(library), "-lm"]
    try:
        done = subprocess.run(command, capture_output=True, text=True, check=False)
    except OSError as error:
        raise RuntimeError(f"compile_c could not run the compiler {compiler!r}: {error}") from None
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed:\n{done.stderr}")
    return {fname: casadi.external(fname, str(library)) for fname in names}
