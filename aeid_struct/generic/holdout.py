"""Whether a record determines a model of its order: the hold-out's rule (``generic.pipeline``'s
``_holdout`` fits the order on the first :data:`~aeid_struct.multi.ESTIMATION_SHARE` of the record
and runs it on the rest; this module says when that flags the estimate, and warns)."""

from __future__ import annotations

import numpy as np

from aeid_struct.generic.boundary import warn_caller
from aeid_struct.multi import ESTIMATION_SHARE

__all__ = ["HOLDOUT_FLOOR", "HOLDOUT_RATIO", "UndeterminedModelWarning", "holdout_flagged",
           "residual_ratio", "warn_holdout"]


class UndeterminedModelWarning(UserWarning):
    """A model of the refined estimate's order, fitted on the first part of its record,
    predicts the rest badly (:func:`holdout_flagged`): the record does not determine a model of
    that order, and the estimate may fail on other data although it fits the record well."""


#: A hold-out fit (``generic.pipeline._holdout``) below this, in %, flags the estimate: a
#: model that predicts its record's last part worse than that part's own mean does.
HOLDOUT_FLOOR = 0.0
#: A hold-out RMS residual above this many times the model's own on the part it was fitted to
#: flags the estimate too (:func:`holdout_flagged`).
HOLDOUT_RATIO = 4.0


def holdout_flagged(holdout: float | None, ratio: float | None) -> bool:
    """Whether a hold-out (``generic.pipeline._holdout``) flags its estimate: its fit below
    :data:`HOLDOUT_FLOOR`, or its RMS residual above :data:`HOLDOUT_RATIO` times the same
    model's on the part it was fitted to.

    Why the ratio too: a fit in % reads the residual against the last part's own variation, so
    a model that fails there on a record whose last part moves a lot still scores above 0 %;
    against the model's own residual on the first part (the noise, for a model the record
    determines) the failure shows whatever the signal. On ``aeid-struct bench-generic``'s
    records a sound model's ratio stayed near 1 and rarely passed 2; ratios above 4 came
    from estimates far below the true model's validation fit.

    Parameters
    ----------
    holdout : float or None
        The hold-out's fit, %.
    ratio : float or None
        Its RMS residual over the model's own on the first part.

    Returns
    -------
    bool
    """
    return holdout is not None and (holdout < HOLDOUT_FLOOR
                                    or (ratio is not None and ratio > HOLDOUT_RATIO))


def warn_holdout(holdout: float | None, fit: float, ratio: float | None = None) -> None:
    """The :class:`UndeterminedModelWarning` of a hold-out that flags its estimate
    (:func:`holdout_flagged`).

    Parameters
    ----------
    holdout : float or None
        ``generic.pipeline._holdout``'s fit, %.
    fit : float
        The estimate's own fit on the whole record, %.
    ratio : float, optional
        ``generic.pipeline._holdout``'s residual ratio.
    """
    if not holdout_flagged(holdout, ratio):
        return
    residual = ("" if ratio is None else
                f", its residual {ratio:.1f} times the model's own on the first part")
    warn_caller(f"a model of this order fitted on the first {ESTIMATION_SHARE:.0%} of the "
                f"record predicts the rest with a fit of {holdout:.1f} %{residual} (the "
                f"estimate's fit on the whole record: {fit:.1f} %): the record does not "
                f"determine a model of this order, which may fail on other data; try a lower "
                f"order or a longer record", UndeterminedModelWarning)


def residual_ratio(cost_rest: float, cost_part: float) -> float | None:
    """The hold-out's RMS residual over the model's own on the part it was fitted to.

    Parameters
    ----------
    cost_rest, cost_part : float
        Mean squared residuals: of the hold-out, and of the fit on its part.

    Returns
    -------
    float or None
        None where either is not finite or the part's is 0 (an exact fit has no noise to
        compare with).
    """
    with np.errstate(all="ignore"):
        ratio = float(np.sqrt(cost_rest / cost_part))
    return ratio if np.isfinite(ratio) else None
