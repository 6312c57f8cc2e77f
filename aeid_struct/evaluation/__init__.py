"""Evaluation: scorecards of identifiers on validation sets, and figures (paper Fig. 3 and
Fig. 4, training curves, pole maps, error distributions, parameter errors).
"""

from aeid_struct.evaluation.comparison import LEG_SIGNALS as LEG_SIGNALS
from aeid_struct.evaluation.comparison import Comparison as Comparison
from aeid_struct.evaluation.comparison import fig3 as fig3
from aeid_struct.evaluation.comparison import fig4 as fig4
from aeid_struct.evaluation.history import training_summary as training_summary
from aeid_struct.evaluation.history import training_table as training_table
from aeid_struct.evaluation.plots import error_cdf as error_cdf
from aeid_struct.evaluation.plots import knowledge_bars as knowledge_bars
from aeid_struct.evaluation.plots import pole_map as pole_map
from aeid_struct.evaluation.plots import training_curves as training_curves
from aeid_struct.evaluation.scorecard import Score as Score
from aeid_struct.evaluation.scorecard import pool as pool
from aeid_struct.evaluation.scorecard import score as score
from aeid_struct.evaluation.scorecard import table as table
from aeid_struct.evaluation.style import METRIC_UNITS as METRIC_UNITS
from aeid_struct.evaluation.style import PARAMETER_UNITS as PARAMETER_UNITS
from aeid_struct.evaluation.style import check_title as check_title
from aeid_struct.evaluation.style import finish_figure as finish_figure
from aeid_struct.evaluation.style import unit_label as unit_label

__all__ = [
    "Comparison",
    "LEG_SIGNALS",
    "METRIC_UNITS",
    "PARAMETER_UNITS",
    "Score",
    "check_title",
    "error_cdf",
    "fig3",
    "fig4",
    "finish_figure",
    "knowledge_bars",
    "pole_map",
    "pool",
    "score",
    "table",
    "training_curves",
    "training_summary",
    "training_table",
    "unit_label",
]
