"""What every figure shares: units of the quantities drawn, axis labels with units, titles that
say what produced a figure, and writing the PNG."""

from __future__ import annotations

from pathlib import Path

#: Units of the leg's physical parameters (``knowledge_bars``, the studies' wear figure).
PARAMETER_UNITS = {"k": "N/m", "d": "N s/m", "m": "kg"}

#: Unit of each per-record error of a ``scorecard.Score`` (``error_cdf``): the Table I step
#: error is a share of the true step response's range (dimensionless).
METRIC_UNITS = {"step": "share of the true step range", "magnitude_db": "dB",
                "phase_rad": "rad", "fit": "%", "k": "%", "d": "%", "m": "%"}


def pyplot():
    """``matplotlib.pyplot``, imported on first use (importing the library draws nothing).

    No backend is forced here, so figures show inline in notebooks; without a display
    matplotlib falls back to Agg by itself, and the CLI selects Agg explicitly.

    Returns
    -------
    module
        ``matplotlib.pyplot``.
    """
    import matplotlib.pyplot as plt

    return plt


def check_title(title) -> None:
    """Refuse a figure title that is neither a string nor None.

    Parameters
    ----------
    title : str or None
        What produced the figure.

    Raises
    ------
    ValueError
        ``title`` is something else.
    """
    if title is not None and not isinstance(title, str):
        raise ValueError(f"title must be a string or None; got {title!r}")


def finish_figure(fig, title, path) -> None:
    """Put the figure's title above the panels' own titles and write the PNG.

    The figures use matplotlib's constrained layout, which makes room for the title.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure.
    title : str or None
        What produced the figure (None or empty: no title).
    path : str or Path or None
        Where to write the PNG (its folder is created); None writes nothing.
    """
    if title:
        fig.suptitle(title, fontsize=10)
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=120)


def unit_label(unit: str) -> str:
    """An axis label's unit part.

    Parameters
    ----------
    unit : str
        The unit, e.g. ``"m"``; empty when the caller gave none.

    Returns
    -------
    str
        ``"[m]"``, or ``"[unit not given]"`` for an empty unit.
    """
    return f"[{unit}]" if unit else "[unit not given]"
