r"""Is the record closed-loop? A test of the residuals against later inputs.

In an open-loop experiment the input does not depend on the output's noise: the residuals
``e = y - yhat`` of a model (noise, plus model error driven by *past* inputs) are uncorrelated
with *later* inputs. Under feedback (``u = C(r - y)``) the controller feeds the noise back:
``u_{k+tau}`` depends on ``e_k`` for ``tau >= 1``. The test is the residual analysis of
model validation (the cross-correlation MATLAB's ``resid`` plots, at positive lags), with the
input prewhitened so that model error cannot leak into later lags through the input's own
correlation:

    u_k = sum_{i=1}^{p} a_i u_{k-i} + w_k            (AR(p) by Yule-Walker, w white)
    r(tau) = sum_k e_k w_{k+tau} / (||e|| ||w||),    tau = 1 .. L
    v = max(1, sum_{|m| <= L} rho_e(m) rho_w(m))     (Bartlett: N var r under open loop)
    z = max_tau |r(tau)| sqrt(N / v)  >  Phi^{-1}(1 - alpha / (2 L))

Under open loop ``r(tau) sqrt(N / v)`` is approximately standard normal for every ``tau``, so
``alpha`` is the false-alarm rate over all ``L`` lags (Bonferroni). What the library does with
a closed-loop record (``generic.pipeline``, step 6): it identifies the plant from ``u`` to
``y`` by output error (the direct method), without a feedthrough where the structure is the
default, and says so (:class:`FeedbackWarning`, ``info["feedback"]``): consistent where the
output noise is white, biased where it is coloured.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.signal
from scipy.stats import norm

from aeid_struct.generic.boundary import warn_caller

__all__ = ["FEEDBACK_ALPHA", "FEEDBACK_LAGS", "PREWHITEN", "QUIET", "FeedbackWarning",
           "feedback_channels", "feedback_test", "warn_feedback"]

#: Later-input lags tested.
FEEDBACK_LAGS = 20
#: Order of the input's prewhitening AR model.
PREWHITEN = 10
#: False-alarm rate of the test over all lags on an open-loop record.
FEEDBACK_ALPHA = 1e-3
#: Residual RMS, relative to the output's, below which nothing is tested: the bias feedback
#: causes scales with the noise fed back, and a residual this small is model error (measured:
#: noise-free open-loop records flagged on 6 of 64 without this bound, none with it).
QUIET = 1e-3


class FeedbackWarning(UserWarning):
    """The record's residuals are correlated with later inputs: it looks closed-loop, and an
    output-error model of the plant is biased by the noise the controller fed back unless it
    has no direct feedthrough and that noise is white."""


def feedback_test(y, y_hat, u, *, lags: int = FEEDBACK_LAGS, order: int = PREWHITEN,
                  alpha: float = FEEDBACK_ALPHA) -> dict | None:
    """The module docstring's test on one record and its model's output.

    Parameters
    ----------
    y, y_hat, u : (steps,) arrays
        Measured output, the model's simulated output (NaN where it has none: the samples
        before the delay, left out with ``u`` at the same samples) and the input.
    lags : int, >= 1
        ``L``, capped at an eighth of the samples.
    order : int, >= 1
        ``p``, capped at a sixteenth of the samples.
    alpha : float in (0, 1)

    Raises
    ------
    ValueError
        Arrays of other shapes.

    Returns
    -------
    dict or None
        ``{"statistic": z, "lag": tau of the largest |r|, "bound": the threshold,
        "detected": z > bound, "lags": L}``; None where the record is too short (fewer than
        64 samples with a model output), the prewhitened input is zero (no test possible) or
        the residual is below :data:`QUIET` of the output (nothing material to be biased).
    """
    y, y_hat, u = (np.asarray(v, dtype=np.float64) for v in (y, y_hat, u))
    if y.ndim != 1 or y_hat.shape != y.shape or u.shape != y.shape:
        raise ValueError(f"y, y_hat and u must be (steps,) arrays of one length; got shapes "
                         f"{y.shape}, {y_hat.shape}, {u.shape}")
    used = np.isfinite(y_hat)
    e, uu = y[used] - y_hat[used], u[used]
    if e.shape[0] < 64:
        return None
    L, p = max(1, min(lags, e.shape[0] // 8)), max(1, min(order, e.shape[0] // 16))
    e, uu = e - e.mean(), uu - uu.mean()
    if not np.linalg.norm(e) > QUIET * np.linalg.norm(y[used] - y[used].mean()):
        return None
    r = np.array([uu[: uu.shape[0] - j] @ uu[j:] for j in range(p + 1)])
    if not r[0] > 0:
        return None
    # Yule-Walker rather than least squares: the Toeplitz solve is the cheaper one and its
    # whitening filter is always stable
    a = scipy.linalg.solve_toeplitz(r[:p], r[1:])
    w = scipy.signal.lfilter(np.r_[1.0, -a], 1.0, uu)[p:]
    e = e[p:]
    scale = np.linalg.norm(e) * np.linalg.norm(w)
    if not scale > 0:
        return None
    N = w.shape[0]
    rho_e, rho_w = _autocorrelation(e, L), _autocorrelation(w, L)
    # Bartlett's variance of a cross-correlation, N var r = sum_m rho_e(m) rho_w(m): 1 for a
    # white w, larger where a smooth residual (model error, no noise) meets what the AR(p)
    # whitening left in w
    var = max(1.0, float(rho_e[0] * rho_w[0] + 2.0 * rho_e[1:] @ rho_w[1:]))
    z = np.array([e[: N - t] @ w[t:] for t in range(1, L + 1)]) / scale * np.sqrt(N / var)
    k = int(np.argmax(np.abs(z)))
    bound = float(norm.ppf(1.0 - alpha / (2 * L)))
    return {"statistic": float(abs(z[k])), "lag": k + 1, "bound": bound,
            "detected": bool(abs(z[k]) > bound), "lags": L}


def feedback_channels(Ys, Y_hats, Us, *, lags: int = FEEDBACK_LAGS, order: int = PREWHITEN,
                      alpha: float = FEEDBACK_ALPHA) -> dict | None:
    """:func:`feedback_test` of every record's every output against every input, ``alpha``
    the false-alarm rate over all of them (Bonferroni: ``alpha / (R p m)`` each).

    Under feedback a controller may close any loop: output ``i``'s noise reaches input ``j``
    wherever the controller reads ``y_i`` for ``u_j``, so every pair is tested.

    Parameters
    ----------
    Ys, Y_hats : sequences of R (steps_r, p) arrays
        Measured outputs and the model's (NaN where it has none).
    Us : sequence of R (steps_r, m) arrays
    lags, order : int
        As :func:`feedback_test`.
    alpha : float in (0, 1)

    Returns
    -------
    dict or None
        The pair furthest above (or nearest to) its bound: :func:`feedback_test`'s result with
        ``record``, ``output`` and ``input`` (indices) added; None where no pair is testable.
    """
    tests = sum(np.shape(Y)[1] * np.shape(U)[1] for Y, U in zip(Ys, Us, strict=True))
    worst = None
    for r, (Y, Y_hat, U) in enumerate(zip(Ys, Y_hats, Us, strict=True)):
        for i in range(np.shape(Y)[1]):
            for j in range(np.shape(U)[1]):
                found = feedback_test(Y[:, i], Y_hat[:, i], U[:, j], lags=lags, order=order,
                                      alpha=alpha / tests)
                if found is not None and (worst is None or found["statistic"] / found["bound"]
                                          > worst["statistic"] / worst["bound"]):
                    worst = found | {"record": r, "output": i, "input": j}
    return worst


def _autocorrelation(x: np.ndarray, lags: int) -> np.ndarray:
    """``rho(0..lags)`` of a zero-mean series (biased estimate, ``rho(0) = 1``)."""
    r = np.array([x[: x.shape[0] - m] @ x[m:] for m in range(lags + 1)])
    return r / r[0]


def warn_feedback(found: dict, strict: bool) -> None:
    """The :class:`FeedbackWarning` of a record that looks closed-loop, attributed to the
    caller.

    Parameters
    ----------
    found : dict
        :func:`feedback_test`'s result (detected), or :func:`feedback_channels`' (naming the
        output and input).
    strict : bool
        Whether the estimate was identified again without its feedthrough.
    """
    several = "output" in found
    if several:
        what = ("the estimate has no direct feedthrough (D = 0): a free D takes up the noise a "
                "controller feeds back in the same sample" if strict else
                "a model with a direct feedthrough takes up the noise a controller feeds back "
                "in the same sample")
    else:
        what = ("the estimate has no direct feedthrough (d = 0): a free d takes up the noise "
                "a controller feeds back in the same sample; pass structure=CCF(order, "
                "feedthrough=True) to keep one" if strict else
                "a model with a direct feedthrough takes up the noise a controller feeds back "
                "in the same sample")
    where = (f" (output {found['output']} against input {found['input']}"
             + (f", record {found['record']}" if found.get("record") else "") + ")"
             if several else "")
    warn_caller(f"the record looks closed-loop: its residuals are correlated with later "
                f"inputs{where} (z = {found['statistic']:.1f} at lag {found['lag']}, bound "
                f"{found['bound']:.2f}); {what}. The output-error fit from u to y is "
                f"consistent under feedback only for white output noise: coloured noise "
                f"(drift, disturbances the plant filters) biases it: identify such a plant "
                f"from an open-loop experiment", FeedbackWarning)
