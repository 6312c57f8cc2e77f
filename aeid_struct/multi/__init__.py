"""One model of several inputs and outputs, or of several experiments of one system
(issue 24): ``ae.identify`` hands such records here.

Layer: above ``identification`` (its :func:`identify` returns an ``Estimate``) and
``simulation``, below ``generic`` (whose ``ae.identify`` passes its encoders' candidates in).

Modules: ``experiments`` (the records checked once, working units), ``realisation`` (the
observer form with a reference output; ``B, D``, initial states and offsets by projection),
``start`` (delays, candidate poles, the relaxed projection, the start), ``fit`` (variable
projection to the output-error optimum; the model in the user's units), ``identify`` (the
steps, order selection, the Estimate), ``comparison`` (a model's fit per output).
"""


from aeid_struct.multi.comparison import compare_channels as compare_channels
from aeid_struct.multi.excitation import unexcited_modes as unexcited_modes
from aeid_struct.multi.experiments import Experiments as Experiments
from aeid_struct.multi.experiments import experiments_of as experiments_of
from aeid_struct.multi.experiments import several as several
from aeid_struct.multi.identify import ESTIMATION_SHARE as ESTIMATION_SHARE
from aeid_struct.multi.identify import EXACT as EXACT
from aeid_struct.multi.identify import ITERATIONS as ITERATIONS
from aeid_struct.multi.identify import MAX_DELAY as MAX_DELAY
from aeid_struct.multi.identify import ORDER_TOLERANCE as ORDER_TOLERANCE
from aeid_struct.multi.identify import PATIENCE as PATIENCE
from aeid_struct.multi.identify import chosen_order as chosen_order
from aeid_struct.multi.identify import fit_from_poles as fit_from_poles
from aeid_struct.multi.identify import identify as identify
from aeid_struct.multi.identify import order_search_done as order_search_done
from aeid_struct.multi.identify import packed as packed
from aeid_struct.multi.identify import parameters as parameters
from aeid_struct.multi.realisation import Layout as Layout
from aeid_struct.multi.realisation import observer_form as observer_form
from aeid_struct.multi.realisation import project as project
from aeid_struct.multi.start import continuous_poles as continuous_poles
from aeid_struct.multi.start import reflected as reflected
from aeid_struct.multi.start import stabilised as stabilised

__all__ = ["ESTIMATION_SHARE", "EXACT", "Experiments", "ITERATIONS", "Layout", "MAX_DELAY",
           "ORDER_TOLERANCE", "PATIENCE", "chosen_order", "compare_channels", "continuous_poles",
           "experiments_of", "fit_from_poles", "identify", "observer_form", "order_search_done",
           "packed", "parameters", "project", "reflected", "several", "stabilised",
           "unexcited_modes"]
