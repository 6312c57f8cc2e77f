"""The tables of the online benchmark (``studies.bench_online``): one Markdown table per part
(tracker, latency, arbitrary excitation, out-of-range flags), each with its legend.

The seam: the benchmark measures and returns JSON-able numbers; this module only reads them, so a
stored result prints without running anything (``format_tables``).
"""

from __future__ import annotations

import math


def _joined(values: dict, fmt: str, names=("k", "d", "m")) -> str:
    """``"a / b / c"`` of every named value, each formatted by ``fmt``; ``-`` for a parameter
    the record does not hold (absent: the rotational leg has no d), ``n/a`` for nan. Every
    name keeps its place, so ``k / - / m`` cannot be read as k and d."""
    def cell(p):
        if p not in values:
            return "-"
        return "n/a" if math.isnan(values[p]) else format(values[p], fmt)

    return " / ".join(cell(p) for p in names)


def _heading(title: str, columns: str, align: str) -> list[str]:
    return [f"### {title}", "", columns, align]


#: The columns of each ``format_tables`` table, printed under it.
LEGENDS = {
    "tracker": "k / d / m RMS %: RMS error of the smoothed estimate relative to the true value "
               "after the baseline windows. true 5 % crossing: when the true k first left its "
               "start by the alarm threshold (5 %). alarm: when the tracker raised it; (false): "
               "before the wear began. update ms: median and 95th percentile wall time of one "
               "update (one window identified, smoothed and checked), one core.",
    "latency": "Wall time of one record through each path, one thread, the paths taking turns; "
               "median and 95th percentile, ms.",
    "excitation": "k / d / m median %: median absolute parameter error over all records, % of "
                  "the true value; '-': the subsystem does not contain the parameter (the "
                  "rotational leg has no d). step err: median Table I step error (share of the "
                  "true response's range). fail: share of records with a parameter that is not "
                  "finite and positive or a step error above 0.05. ms / record: the "
                  "refinement's wall time per record. Noise: standard deviation as a share of "
                  "max |y|.",
    "flags": "flagged: share of estimates that Estimate.outside flags (for legs inside the "
             "range: false flags). before / after refine='auto': mean absolute parameter "
             "errors, % of the true value, of the encoder alone and after refining the flagged "
             "records; '-': a parameter the record does not hold.",
}


def format_tables(result: dict) -> str:
    """Markdown tables of an online benchmark, each with its legend (``LEGENDS``).

    Parameters
    ----------
    result : dict
        What ``bench_online.bench_online`` returned (or a part of it).

    Returns
    -------
    str
    """
    out = []
    if "tracker" in result:
        out += _heading("Tracker (wear scenario, one update = one window identified)",
                        "| engine | seed | k / d / m RMS % | true 5 % crossing | alarm | "
                        "update ms median / p95 |", "|---|---:|---|---:|---:|---:|")
        for r in result["tracker"]:
            out.append(f"| {r['engine']} | {r['seed']} | {_joined(r['rms'], '.2f')}"
                       + f" | {r['drift_time']:.1f} s | {r['alarm_time']:.1f} s"
                       + (" (false)" if r["false_alarm"] else "")
                       + f" | {r['latency_ms']:.3f} / {r['latency_p95_ms']:.3f} |")
        out += ["", LEGENDS["tracker"], ""]
    if "latency" in result:
        out += _heading("Latency of one record, one thread", "| path | median ms | p95 ms |",
                        "|---|---:|---:|")
        for name, t in result["latency"].items():
            out.append(f"| {name} | {t['median_ms']:.3f} | {t['p95_ms']:.3f} |")
        out += ["", LEGENDS["latency"], ""]
    for key, rows in result.get("excitation", {}).items():
        out += _heading(f"Arbitrary excitation: {key}",
                        "| input | noise | encoder k / d / m median % | step err | fail | "
                        "+ refine k / d / m median % | step err | fail | ms / record |",
                        "|---|---:|---|---:|---:|---|---:|---:|---:|")
        for r in rows:
            e = r["encoder"]
            line = (f"| {r['kind']} | {100 * r['noise']:g} % | {_joined(e, '.2f')}"
                    f" | {e['step_error']:.1e} | {100 * e['failures']:.0f} % |")
            if "refined" in r:
                f = r["refined"]
                line += (f" {_joined(f, '.3f')} | {f['step_error']:.1e} | "
                         f"{100 * f['failures']:.0f} % | {f['ms']:.1f} |")
            out.append(line)
        out += ["", LEGENDS["excitation"], ""]
    for key, rows in result.get("flags", {}).items():
        out += _heading(f"Out-of-range flags: {key}",
                        "| noise | legs | flagged | mean % before (k / d / m) "
                        "| after refine='auto' |", "|---:|---|---:|---|---|")
        for r in rows:
            where = "inside" if r["beyond"] == 0 else f"{100 * r['beyond']:.0f} % beyond"
            line = f"| {100 * r['noise']:g} % | {where} | {100 * r['flagged']:.1f} % |"
            if "before" in r:
                line += f" {_joined(r['before'], '.2f')} | {_joined(r['after'], '.2f')} |"
            out.append(line)
        out += ["", LEGENDS["flags"], ""]
    return "\n".join(out)
