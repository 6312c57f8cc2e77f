"""Calibration of a trained identifier: the training range and the flag thresholds that
``Estimate.outside`` uses to flag estimates outside what the identifier was trained on.
"""

from __future__ import annotations

import numpy as np

from aeid_struct.identification import FLAG_FALSE_RATE, Identifier, excess
from aeid_struct.training.datasets import Records, holdout_split, one_per_output, records
from aeid_struct.training.objective import true_elements

#: Held-out records the calibration identifies at most (a fixed random subset of them).
#: Why: each is identified with the identifier's head, which for a physical structure of
#: several channels costs tens of milliseconds a record, so the whole held-out share of a
#: large run took minutes after its training budget; 1,000 leave 15 records in the 1.5 % tail
#: the flag thresholds are quantiles of.
CALIBRATION_RECORDS = 1000


def recalibrate(ident: Identifier, family) -> Identifier:
    """Recompute ``ident``'s training range and flag thresholds (``Estimate.outside``) as
    ``train()`` does at its end, for a file trained before them.

    The run's records and held-out split are re-created from the settings it recorded
    (``meta["train"]["config"]``) and ``family``; the weights are untouched.

    Parameters
    ----------
    ident : Identifier
        Trained by ``train()`` (its settings in ``meta["train"]["config"]``); one record or
        several.
    family : LegFamily, PoleFamily or any family
        The family it was trained on.

    Returns
    -------
    Identifier
        ``ident`` itself, with ``meta["training_range"]`` replaced.

    Raises
    ------
    ValueError
        ``ident`` is not an Identifier with its training settings.
    """
    if not isinstance(ident, Identifier):
        raise ValueError(f"ident must be an Identifier (ae.Identifier.load(path)); "
                         f"got {type(ident).__name__}")
    cfg = ident.meta.get("train", {}).get("config")
    if not cfg:
        raise ValueError("ident must carry its training settings (meta['train']['config'])")
    rec = records(family, cfg["count"], steps=cfg["steps"], dt=cfg["dt"],
                  excitation_kind=cfg["excitation"], seed=cfg["seed"],
                  warmup=cfg.get("warmup", 0))
    held = holdout_split(cfg["count"], cfg["holdout"], cfg["seed"])[1]
    ident.meta["training_range"] = training_range(ident, rec, held, max(cfg["noise"]),
                                                   cfg["seed"] + 4)
    return ident


def training_range(ident: Identifier, rec: Records, held: np.ndarray, noise: float,
                   seed: int) -> dict:
    """What ``Estimate.outside`` compares with (``ident.meta["training_range"]``).

    Per free element and physical parameter: its ``[lo, hi]`` over the training family and the
    identifier's 90th-percentile absolute error on the held-out records at the largest training
    noise (at most ``CALIBRATION_RECORDS`` of them, a subset drawn with ``seed``). And the two
    flag thresholds calibrated on those records, so that each flags
    ``FLAG_FALSE_RATE`` of them: ``excess`` (its ``1 - FLAG_FALSE_RATE`` quantile) and ``fit``
    (NRMSE %, its ``FLAG_FALSE_RATE`` quantile).

    Parameters
    ----------
    ident : Identifier
        Trained (one record, or several: the fit threshold is then on each system's lowest
        record fit, as ``Estimate.outside`` reads it).
    rec : Records
        The run's records.
    held : (H,) int array
        The held-out indices.
    noise : float
        The largest training noise level (std relative to ``max|y|``).
    seed : int
        Seeds the noise draw.

    Returns
    -------
    dict
        ``{"elements": {name: [lo, hi, err90]}, "physical": {...}, "excess": float,
        "fit": float}``.
    """
    systems = rec.systems
    X = true_elements(ident.structure, systems)
    if X is None:
        X = ident.structure.elements_of(systems.A, systems.b, systems.c, systems.d).numpy()
    rng = np.random.default_rng(seed)
    if held.size > CALIBRATION_RECORDS:
        held = np.sort(np.random.default_rng([seed, 1]).choice(held, CALIBRATION_RECORDS,
                                                                replace=False))
    several = ident.records > 1
    ys, us = (rec.y_clean, rec.u) if several else ((rec.y_clean,), (rec.u,))
    y = tuple(one_per_output(
        lambda r: ys[r][held] + noise * np.abs(ys[r][held]).max(axis=1, keepdims=True)
        * rng.normal(size=ys[r][held].shape), len(ys), getattr(ident.structure, "groups", None)))
    u = tuple(v[held] for v in us)
    est = ident.identify(y, u) if several else ident.identify(y[0], u[0])
    out: dict[str, dict] = {"elements": {}, "physical": {}}
    for i, name in enumerate(ident.structure.element_names):
        if name in ident.structure.free_names:
            err = np.abs(np.asarray(est.elements[name]) - X[held, i])
            out["elements"][name] = [float(X[:, i].min()), float(X[:, i].max()),
                                     float(np.nanpercentile(err, 90))]
    for name, value in (est.physical or {}).items():
        if name in systems.params:
            truth = systems.params[name]
            err = np.abs(np.asarray(value) - truth[held])
            out["physical"][name] = [float(truth.min()), float(truth.max()),
                                     float(np.nanpercentile(err, 90))]
    # The flag thresholds (Estimate.outside): the quantiles of excess and fit on these
    # in-range records that flag FLAG_FALSE_RATE of them each.
    beyond = excess({**est.elements, **(est.physical or {})}, out)
    out["excess"] = float(np.nanquantile(beyond, 1.0 - FLAG_FALSE_RATE))
    # several records: any record's low fit flags its system (Estimate.outside), so the
    # threshold is the quantile of each system's lowest
    fit = np.min(est.fit, axis=-1) if several else est.fit
    out["fit"] = float(np.nanquantile(fit, FLAG_FALSE_RATE))
    return out
