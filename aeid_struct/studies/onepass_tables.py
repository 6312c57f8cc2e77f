"""The tables of the one-pass study (``studies.onepass_bench``): per identifier one accuracy and
one time table, each row one input kind and noise level, every method side by side, and the
issue's targets read off them."""

from __future__ import annotations

import math

from aeid_struct.studies.onepass_bench import (
    BASELINES,
    METHODS,
    TARGET_LS_OVER_ONE_PASS,
    TARGET_NOISE_FREE_PERCENT,
    TARGET_VS_OPTIMUM,
)

__all__ = ["ONEPASS_LEGEND", "format_onepass_tables"]

#: The column headings of the methods (``METHODS`` order).
_SHORT = {"encoder": "encoder", "one pass": "one pass", "encoder + refine": "+ refine (optimum)",
          "least squares (cold)": "LS cold", "CasADi (cold)": "CasADi cold", "n4sid": "n4sid"}

#: The columns of :func:`format_onepass_tables`, printed under the tables.
ONEPASS_LEGEND = """\
Columns:
- input: the excitation of the records (steps of random height and timing, PRBS, multisine,
  filtered noise); the records have the identifier's format (leg-stable-any and
  leg-stable-window: mid-motion windows; leg-unstable-any: from rest). leg-stable-window was
  trained on PRBS windows alone, its natural input.
- noise: white noise added to each record, standard deviation as a share of max |y|; errors
  are against the true k, d, m of the simulated leg.
- k / d / m %: median over records of |estimate / truth - 1| in %; '-': a parameter the
  subsystem does not contain (the rotational leg has no d); 'inf': more than half the records
  failed; [n % fail]: the share of records whose estimate failed (an exception, a reported
  failure, or a parameter that is not finite and positive), counted as infinite errors.
- encoder: the encoder alone, the paper's architecture (head None). one pass: the encoder and
  the separable head (a fixed number of Levenberg-Marquardt iterations on the
  variable-projection cost in the physics structure: c1 = 0; rotational leg also a1 = 0).
  + refine (optimum): identify(refine=True), the head iterated to convergence: the
  least-squares optimum in the physics structure.
- LS cold: baselines.least_squares from its generic start in the physics structure (records
  from rest); on windows its Record form: a free CCF with the initial state and an output
  offset, started from n4sid. CasADi cold: baselines.casadi_cold in the physics structure
  (records from rest); on windows refinement.refine_record (the initial state projected) from
  baselines.generic_start. n4sid: baselines.n4sid, order 2 (Record form on windows).
- encoder / optimum, one pass / optimum: per parameter the method's median error over the
  optimum's, same records; '-' on noise-free rows (the optimum is exact there).
- ms: median wall time of one batch-1 call (one record), one thread, over the timed records,
  the calls back to back after an untimed warm-up call. LS cold / one pass: the ratio of the
  two. rec/s: records per second of one batched call (best of two; one for + refine), one
  thread."""


def _num(v: float) -> str:
    """A median error or ratio in a fixed width: 3 significant places below 10, fewer above."""
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "n/a"
    if math.isinf(v):
        return "inf"
    if abs(v) >= 1000:
        return f"{v:.2g}"
    if abs(v) >= 100:
        return f"{v:.0f}"
    return f"{v:.1f}" if abs(v) >= 10 else f"{v:.3f}"


def _times(v: float) -> str:
    """A ratio near 1 to two decimals (the target is 1.2), a large one to whole units."""
    return f"{v:.2f}" if v < 10 else f"{v:.0f}"


def _triple(values: dict, names, fmt=_num) -> str:
    """``"k / d / m"`` with every name in its place, ``-`` for one the row does not hold."""
    return " / ".join("-" if p not in values else
                      ("-" if values[p] is None else fmt(values[p])) for p in names)


def _accuracy_cell(entry: dict | None, names) -> str:
    if entry is None:
        return ""
    cell = _triple(entry["median"], names)
    if entry["failures"] > 0:
        cell += f" [{100 * entry['failures']:.0f} % fail]"
    return cell


def _accuracy_table(rows: list, names, methods) -> list[str]:
    head = ("| input | noise | " + " | ".join(f"{_SHORT[m]} k / d / m %" for m in methods)
            + " | encoder / optimum | one pass / optimum |")
    lines = [head, "|---|---:|" + "---|" * (len(methods) + 2)]
    for r in rows:
        cells = [_accuracy_cell(r["methods"].get(m), names) for m in methods]
        ratios = [_triple(r["vs_optimum"][m], names, _times)
                  for m in ("encoder", "one pass")]
        lines.append(f"| {r['kind']} | {100 * r['noise']:g} % | " + " | ".join(cells + ratios)
                     + " |")
    return lines


def _time_table(rows: list, methods) -> list[str]:
    ours = [m for m in methods if m not in BASELINES]
    baselines = [m for m in methods if m in BASELINES]
    head = ("| input | noise | " + " | ".join(f"{_SHORT[m]} ms" for m in methods)
            + (" | LS cold / one pass" if "least squares (cold)" in baselines else "")
            + " | " + " | ".join(f"{_SHORT[m]} rec/s" for m in ours) + " |")
    ncols = len(methods) + len(ours) + ("least squares (cold)" in baselines)
    lines = [head, "|---|---:|" + "---:|" * ncols]
    for r in rows:
        m = r["methods"]
        cells = [f"{m[k]['ms']:.3f}" for k in methods]
        if "least squares (cold)" in baselines:
            cells.append(f"{r['ls_over_one_pass']:.1f}x")
        cells += [f"{m[k]['per_s']:,.0f}" for k in ours]
        lines.append(f"| {r['kind']} | {100 * r['noise']:g} % | " + " | ".join(cells) + " |")
    return lines


def _head_text(entry: dict) -> str:
    head = entry["head"]
    fixed = ", ".join(f"{k} = {v:g}" for k, v in head["fixed"].items()) or "nothing"
    where = "stored in the file" if entry["head_in_file"] else "default head, the file has none"
    return f"head: {head['iterations']} iterations, fixed {fixed} ({where})"


def _targets_text(result: dict) -> list[str]:
    lines = [f"Targets (PRBS, multisine, filtered noise): one pass <= "
             f"{TARGET_NOISE_FREE_PERCENT:g} % noise-free; <= {TARGET_VS_OPTIMUM:g}x the "
             f"optimum's median error at 1-5 % noise; LS cold / one pass >= "
             f"{TARGET_LS_OVER_ONE_PASS:g}x (all inputs)."]
    for name, t in result.get("targets", {}).items():
        def show(value, met, fmt):
            if value is None:
                return "not measured"
            return format(value, fmt) + (" (met)" if met else " (missed)")

        lines.append(f"- {name}: noise-free max "
                     f"{show(t['noise_free_max_percent'], t['noise_free_met'], '.3g')} %; "
                     f"worst one pass / optimum "
                     f"{show(t['vs_optimum_max'], t['vs_optimum_met'], '.2f')}; smallest LS "
                     f"cold / one pass {show(t['ls_over_one_pass_min'], t['time_met'], '.1f')}")
    return lines


def format_onepass_tables(result: dict, *, legend: bool = True) -> str:
    """Markdown tables of a one-pass study: per identifier its accuracy and its time table,
    then the targets and (with ``legend``) :data:`ONEPASS_LEGEND`.

    Parameters
    ----------
    result : dict
        What ``onepass_bench.bench_onepass`` returned.
    legend : bool
        Put the column definitions under the tables.

    Returns
    -------
    str
    """
    s = result["settings"]
    out = [f"One pass at the optimum: (a)-(c) on {s['count']} records per row; the cold "
           f"baselines and every batch-1 time on the first {s['timed']}; batched calls of "
           f"{s['batch']} records; {s.get('threads', 1)} thread."]
    for name, entry in result["identifiers"].items():
        rows = entry["rows"]
        if not rows:
            continue
        names = [p for p in ("k", "d", "m") if p in rows[0]["methods"]["one pass"]["median"]]
        methods = [m for m in METHODS if m in rows[0]["methods"]]
        out += ["", f"### {name}: accuracy ({_head_text(entry)})", ""]
        out += _accuracy_table(rows, names, methods)
        out += ["", f"### {name}: time", ""]
        out += _time_table(rows, methods)
    out += [""] + _targets_text(result)
    if "seconds" in result:
        out.append(f"Study wall time: {result['seconds']:.0f} s.")
    if legend:
        out += ["", ONEPASS_LEGEND]
    return "\n".join(out)
