"""Comparison figures: what is drawn is the data given (lines, crosses, shares); PNGs written."""

import math

import numpy as np
import pytest

from aeid_struct import plots
from aeid_struct.scorecard import Score


def _history(n=5, skip_at=None):
    skipped = [0] * n
    if skip_at is not None:
        skipped[skip_at] = 2
    return {"holdout_loss": list(np.geomspace(1, 1e-3, n)),
            "grad_norm_max": list(np.geomspace(1e3, 1, n)), "skipped": skipped}


def _score(name, step, stable, poles):
    step = np.asarray(step, dtype=float)
    return Score(name, {"step": step, "fit": 100 - step, "stable": np.asarray(stable),
                        "magnitude_db": step, "phase_rad": step}, np.asarray(poles), 0.1)


def test_training_curves(tmp_path):
    path = tmp_path / "sub" / "curves.png"
    fig = plots.training_curves({"CCF": [_history(), _history(skip_at=2)], "MCF": _history()},
                                path=path)
    assert path.stat().st_size > 0
    ax_loss, ax_grad = fig.axes
    assert len(ax_loss.lines) == 3 and ax_loss.get_yscale() == "log"
    np.testing.assert_allclose(ax_loss.lines[0].get_ydata(), _history()["holdout_loss"])
    # the epoch with skipped batches is marked on the gradient panel (3 curves + 1 marker)
    assert len(ax_grad.lines) == 4
    marker = ax_grad.lines[2]
    np.testing.assert_array_equal(marker.get_xdata(), [3])
    assert [t.get_text() for t in ax_loss.get_legend().get_texts()] == ["CCF", "MCF"]
    with pytest.raises(ValueError, match="histories must map"):
        plots.training_curves({})
    with pytest.raises(ValueError, match=r"histories\['x'\] must be train\(\) histories"):
        plots.training_curves({"x": {"loss": [1.0]}})


def test_pole_map_marks_unstable_estimates(tmp_path):
    poles = np.array([[-1 + 2j, -1 - 2j], [0.5 + 1j, 0.5 - 1j], [-3 + 0j, -0.2 + 0j]])
    s = _score("CCF", [0.1, 0.2, 0.3], [True, False, True], poles)
    fig = plots.pole_map([s, s], path=tmp_path / "poles.png", reference=poles)
    assert len(fig.axes) == 2 and (tmp_path / "poles.png").exists()
    ax = fig.axes[0]
    true, good, bad = ax.lines[:3]
    np.testing.assert_allclose(bad.get_xdata(), [0.5, 0.5])
    np.testing.assert_allclose(bad.get_ydata(), [1.0, -1.0])
    assert len(good.get_xdata()) == 4 and len(true.get_xdata()) == 6
    assert "66.7% stable" in ax.get_title()
    with pytest.raises(ValueError, match="scores must hold"):
        plots.pole_map([])


def test_error_cdf_counts_overflow(tmp_path):
    a = _score("a", [0.1, 0.01, math.inf, 0.001], [True] * 4, np.zeros((4, 1)))
    fig = plots.error_cdf([a], path=tmp_path / "cdf.png")
    line = fig.axes[0].lines[0]
    np.testing.assert_allclose(line.get_xdata(), [0.001, 0.01, 0.1])
    np.testing.assert_allclose(line.get_ydata(), [0.25, 0.5, 0.75])     # never reaches 1
    assert fig.axes[0].get_legend().get_texts()[0].get_text() == "a (1 inf)"
    with pytest.raises(ValueError, match="'k' is missing from"):
        plots.error_cdf([a], metric="k")
    import matplotlib.pyplot as plt

    fig2, ax = plt.subplots()
    assert plots.error_cdf([a], ax=ax) is fig2


def test_knowledge_bars_draw_the_mean_errors_over_valid_estimates(tmp_path):
    def scored(name, k, valid):
        base = _score(name, [0.1, 0.1, 0.1], [True] * 3, np.zeros((3, 2)))
        return Score(name, {**base.per_record, "k": np.asarray(k, dtype=float),
                            "valid": np.asarray(valid)}, base.poles, 0.1)

    scores = [scored("CCF", [1.0, 3.0, 1e6], [True, True, False]),
              scored("physical", [2.0, 2.0, 2.0], [True] * 3)]
    path = tmp_path / "bars.png"
    fig = plots.knowledge_bars({"5 % noise": scores}, parameters=("k",), path=path)
    assert path.stat().st_size > 0
    ax = fig.axes[0]
    heights = [p.get_height() for p in ax.patches]
    assert heights == pytest.approx([2.0, 2.0])           # the invalid 1e6 is left out
    notes = [t.get_text() for t in ax.texts]
    assert notes == ["33% invalid"]
    with pytest.raises(ValueError, match=r"groups must map at least one title"):
        plots.knowledge_bars({})
