"""``aeid-struct identify RECORD --order N`` for a record of several outputs or inputs
(numbered columns ``u1, u2, ..., y1, y2, ...``): the model ``A, B, C, D`` of
``aeid_struct.identify`` (``multi.identify``: the observer form, a delay per input, an offset
per output), printed and carried by the JSON.
"""

from __future__ import annotations

import argparse

import numpy as np

__all__ = ["order_and_hold", "print_channels", "refinement_line", "summary_channels",
           "unexcited_line", "unexcited_of"]


def order_and_hold(s: dict) -> tuple[str, str]:
    """The printout's words on how the order was chosen and the input's hold, for a summary
    of either printout (one channel or several).

    Parameters
    ----------
    s : dict
        A summary with ``order_fits`` and ``intersample``.

    Returns
    -------
    chosen, held : str
    """
    chosen = "" if s["order_fits"] is None else " selected by validation fit (" + ", ".join(
        f"order {n}: {f:.2f} %" for n, f in s["order_fits"].items()) + ")"
    return chosen, " (held between samples)" if s["intersample"] == "zoh" else ""


def refinement_line(s: dict) -> str:
    """The printout's line on the refinement (``refined``, ``refine`` of a summary).

    Parameters
    ----------
    s : dict

    Returns
    -------
    str
    """
    return ("refined over the whole record (output error)" if s["refined"] else
            "not refined (--no-refine)" if not s["refine"] else
            "not refined: the refinement did not lower the residual")


def unexcited_of(est) -> list[dict]:
    """``info["unexcited"]`` of an estimate as the JSON carries it (the pole's frequency and
    real part in rad/s instead of a complex number).

    Parameters
    ----------
    est : Estimate

    Returns
    -------
    list of dict
    """
    return [{"frequency_rad_s": float(m["pole"].imag), "real_part": float(m["pole"].real),
             "damping": m["damping"], "snr": m["snr"], "gain": m["gain"]}
            for m in est.info.get("unexcited", [])]


def unexcited_line(s: dict) -> str | None:
    """The printout's line on modes the record does not determine (``unexcited`` of a
    summary), or None where there are none.

    Parameters
    ----------
    s : dict

    Returns
    -------
    str or None
    """
    if not s["unexcited"]:
        return None
    return ("not determined by the record (the output holds only noise there; --order auto "
            "chooses an order by validation): lightly damped modes at " + ", ".join(
                f"{m['frequency_rad_s']:.4g} rad/s (damping {m['damping']:.3f}, gain "
                f"{m['gain']:.3g} x the model's where the input is)" for m in s["unexcited"]))


def unstable_of(est) -> dict | None:
    """``info["unstable"]`` of an estimate held to stable models (``--stable``, or the modal
    form) as the JSON carries it: the unstable model's poles (real and imaginary parts, in the
    record's time unit) and fit % (per output for several), or None where there is none.

    Parameters
    ----------
    est : Estimate

    Returns
    -------
    dict or None
    """
    found = est.info.get("unstable")
    if found is None:
        return None
    poles = np.sort_complex(np.asarray(found["poles"], dtype=complex))
    return {"poles_real": poles.real.tolist(), "poles_imag": poles.imag.tolist(),
            "fit_percent": np.atleast_1d(found["fit"]).astype(float).tolist()}


def unstable_line(s: dict) -> str | None:
    """The printout's line on a stable estimate whose record's best model is unstable
    (``unstable`` of a summary), or None.

    Parameters
    ----------
    s : dict

    Returns
    -------
    str or None
    """
    found = s["unstable"]
    if found is None:
        return None
    poles = ", ".join(f"{re:.4g}{im:+.4g}j" if im else f"{re:.4g}"
                      for re, im in zip(found["poles_real"], found["poles_imag"], strict=True))
    fits = ", ".join(f"{f:.2f}" for f in found["fit_percent"])
    return (f"held stable: the record's best model is unstable (poles {poles}; fit {fits} %), "
            f"so the estimate is the best stable model, not the system")


def summary_channels(est, record, args: argparse.Namespace, source: str, figure) -> dict:
    """The estimate of several channels as the JSON and the printout carry it.

    Parameters
    ----------
    est : Estimate
        Of ``aeid_struct.identify`` on ``record``.
    record : Record
        ``y (steps, p)``, ``u (steps, m)``.
    args : argparse.Namespace
    source : str
        Where the inputs came from.
    figure : dict or None
        The compare figure's path and fit.

    Returns
    -------
    dict
    """
    fit = np.atleast_1d(np.asarray(est.fit, dtype=np.float64))
    fits = est.info.get("order_fits")
    return {
        "record": args.model, "steps": record.steps, "dt": record.dt, "input": source,
        "intersample": record.intersample, "outputs": record.outputs, "inputs": record.inputs,
        "order": int(est.A.shape[0]),
        "order_fits": None if fits is None else {str(n): f for n, f in sorted(fits.items())},
        # info["reference"]: the output (from 0) whose row of C is (1, 0, ..., 0)
        "structure": f"observer form of y{int(est.info['reference']) + 1}",
        "A": est.A, "B": est.B, "C": est.C, "D": est.D,
        "delay_samples": np.atleast_1d(est.delay).astype(int).tolist(),
        "delay_seconds": (np.atleast_1d(est.delay) * record.dt).tolist(),
        "delay_estimated": args.delay is None,
        "x0": est.x0, "offset": np.atleast_1d(est.offset).tolist(),
        "fit_percent": fit.tolist(), "fit_overall_percent": float(np.mean(fit)),
        "refined": bool(est.refined), "refine": not args.no_refine,
        "seconds": float(est.seconds), "figure": figure, "unexcited": unexcited_of(est),
        "stable": bool(args.stable), "unstable": unstable_of(est),
    }


def print_channels(s: dict, est) -> None:
    """Print :func:`summary_channels`' summary.

    Parameters
    ----------
    s : dict
    est : Estimate
    """
    np.set_printoptions(precision=6, suppress=False)
    chosen, held = order_and_hold(s)
    print(f"{s['record']}: {s['steps']} samples at dt = {s['dt']:g} s, {s['outputs']} outputs, "
          f"{s['inputs']} inputs; inputs: {s['input']}{held}")
    print(f"order {s['order']}{chosen}, {s['structure']}")
    for name in ("A", "B", "C", "D"):
        print(f"{name} =\n", np.asarray(getattr(est, name)))
    print("delay per input: " + ", ".join(
        f"u{j + 1}: {d} samples = {t:g} s" for j, (d, t) in enumerate(
            zip(s["delay_samples"], s["delay_seconds"], strict=True)))
        + (" (estimated)" if s["delay_estimated"] else " (given)"))
    print("initial state x0 =", est.x0)
    print("output offsets = " + ", ".join(f"y{i + 1}: {o:.6g}"
                                          for i, o in enumerate(s["offset"])))
    print("fit: " + ", ".join(f"y{i + 1}: {f:.2f} %" for i, f in enumerate(s["fit_percent"]))
          + f"; mean {s['fit_overall_percent']:.2f} % (NRMSE, initial state and offsets "
          f"fitted)")
    print(refinement_line(s))
    for line in (unexcited_line(s), unstable_line(s)):
        if line is not None:
            print(line)
    print(f"time: {1e3 * s['seconds']:.1f} ms")
    if s["figure"] is not None:
        print(f"wrote {s['figure']['path']} (compare: mean fit "
              f"{float(np.mean(s['figure']['fit_percent'])):.2f} %)")
