"""The argparse machinery every subcommand's options share: the help layout, the parser class
whose errors are one line, and the argument types that check numbers.

The seam: this is how an option is read, not which options a subcommand has, so the modules that
add subcommands (``parser``, ``train_options``, ``bench_options``) all build on it and none on
another. Importing it imports neither torch nor CasADi.
"""

from __future__ import annotations

import argparse
import math
import textwrap

from aeid_struct.cli.errors import InputError


class Formatter(argparse.HelpFormatter):
    """argparse's help layout, keeping blank-line paragraphs and names such as leg-stable-any
    whole (textwrap would break them at the hyphens)."""

    def _split_lines(self, text: str, width: int) -> list[str]:
        return textwrap.wrap(" ".join(text.split()), width, break_on_hyphens=False)

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        return "\n\n".join(textwrap.fill(" ".join(p.split()), width, initial_indent=indent,
                                          subsequent_indent=indent, break_on_hyphens=False)
                            for p in text.split("\n\n"))


class Parser(argparse.ArgumentParser):
    """argparse, with its errors as one line (no usage block) through ``main``."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", Formatter)    # subcommands inherit the class
        super().__init__(*args, **kwargs)

    def error(self, message: str):
        where = self.prog.removeprefix("aeid-struct").strip()
        raise InputError(f"{where + ': ' if where else ''}{message} "
                         f"(see '{self.prog} --help')")


def number(kind: type, low: float | None = None, *, strict: bool = True):
    """An argparse type: a finite ``kind`` (int or float), above ``low`` (or at least it).

    Parameters
    ----------
    kind : type
        ``int`` or ``float``: what the text is read as.
    low : float, optional
        The bound; default none.
    strict : bool
        Above ``low`` (True) or at least ``low`` (False).

    Returns
    -------
    callable
        ``parse(text)``: the value, or an ``argparse.ArgumentTypeError`` that says what was
        expected and what came.
    """
    what = "an integer" if kind is int else "a finite number"
    if low is not None:
        what += f" {'>' if strict else '>='} {low:g}"

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}; got {text!r}") from None
        if not math.isfinite(value) or (low is not None
                                        and (value <= low if strict else value < low)):
            raise argparse.ArgumentTypeError(f"expected {what}; got {text!r}")
        return value

    return parse


#: The argument types most options use: > 0, an integer > 0, and >= 0 (a noise share).
POSITIVE = number(float, 0)
POSITIVE_INT = number(int, 0)
FRACTION = number(float, 0, strict=False)
