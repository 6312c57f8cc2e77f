"""Benchmarks of the library's hot paths (the ``aeid-struct bench`` command prints them).

Decoder (``bench_decoder``): wall-clock time of one forward + backward pass of the decoder, the
operation a training step repeats, on the same data in one run, for

* the default log-depth method (``decoder._simulate``: chunked, a Toeplitz matmul within chunks and
  a scan across them),
* the two alternatives measured against it: Markov parameters + FFT (``decoder._simulate_fft``) and
  the odd-even scan (``decoder._simulate_scan``),
* the plain per-step loop (``decoder._simulate_loop``).

The data: ``batch`` random stable systems of order ``n`` (a Gaussian matrix shifted to put its
rightmost eigenvalue at -1 rad/s), a standard-normal input of ``steps`` samples, ``dt = 0.01``; the
pass is ``y = simulate(A, b, c, d, u)``, ``sum(y^2).backward()`` with gradients for ``A, b, c, d``.
Each entry is the median over ``repeats`` passes after one warm-up pass; the methods take turns so
that a change in machine load hits all alike. ``threads`` (default 1) sets torch's intra-op threads
for the run; CPU timings depend on it and on other load on the machine.
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial

import numpy as np
import torch

from aeid_struct.simulation import simulate_batch as _simulate
from aeid_struct.simulation import simulate_loop as _simulate_loop
from aeid_struct.studies.bench_kernels import simulate_fft as _simulate_fft
from aeid_struct.studies.bench_kernels import simulate_scan as _simulate_scan

__all__ = ["DecoderTiming", "IDENTIFICATION_LEGEND", "bench_decoder", "bench_identification",
           "format_decoder_table", "format_identification_table"]

_METHODS = {
    "default": _simulate,
    "fft": _simulate_fft,
    "scan": _simulate_scan,
    "loop": _simulate_loop,
}


@dataclass(frozen=True, kw_only=True)
class DecoderTiming:
    """One row of the decoder benchmark.

    Attributes
    ----------
    steps : samples per record.
    dtype : ``"float32"`` or ``"float64"``.
    default_ms : median forward + backward time of the default decoder (``simulate``: chunked),
        milliseconds.
    fft_ms : the same for Markov parameters + FFT convolution.
    scan_ms : the same for the odd-even scan.
    loop_ms : the same for the per-step loop.
    speedup : ``loop_ms / default_ms``.
    batch : records per pass.
    """

    steps: int
    dtype: str
    default_ms: float
    fft_ms: float
    scan_ms: float
    loop_ms: float
    speedup: float
    batch: int


def _systems(batch: int, n: int, dtype: torch.dtype, generator: torch.Generator):
    """Random stable ``(A, b, c, d)``: Gaussian ``A`` shifted so that max Re(eig) = -1."""
    A = 3.0 * torch.randn(batch, n, n, generator=generator, dtype=torch.float64)
    shift = torch.linalg.eigvals(A).real.amax(dim=-1) + 1.0
    A = A - shift[:, None, None] * torch.eye(n, dtype=torch.float64)
    b = torch.randn(batch, n, generator=generator, dtype=torch.float64)
    c = torch.randn(batch, n, generator=generator, dtype=torch.float64)
    d = torch.randn(batch, generator=generator, dtype=torch.float64)
    return tuple(x.to(dtype) for x in (A, b, c, d))


def _pass_ms(method: Callable, system, u: torch.Tensor, dt: float) -> float:
    A, b, c, d = (x.detach().requires_grad_() for x in system)
    start = time.perf_counter()
    method(A, b, c, d, u, dt).square().sum().backward()
    return 1e3 * (time.perf_counter() - start)


def bench_decoder(
    batch: int = 256,
    steps: Sequence[int] = (100, 300, 1000),
    dtype: torch.dtype = torch.float32,
    repeats: int = 5,
    *,
    n: int = 2,
    dt: float = 0.01,
    threads: int | None = 1,
    seed: int = 0,
) -> list[DecoderTiming]:
    """Time forward + backward of the default decoder, the alternatives and the per-step loop.

    Parameters
    ----------
    batch : records per pass, >= 1.
    steps : record lengths to time, each >= 2.
    dtype : torch.float32 or torch.float64.
    repeats : timed passes per method and length (the median is reported), >= 1.
    n : system order, >= 1.
    dt : sample time, > 0.
    threads : torch intra-op threads during the run (restored afterwards); None leaves torch's
        setting alone. 1 by default: reproducible, and robust to other load (on a busy machine,
        threads that wait for each other slow the decoder's small kernels down many times).
    seed : seeds the random systems and inputs.

    Returns
    -------
    One ``DecoderTiming`` per entry of ``steps``.
    """
    if dtype not in (torch.float32, torch.float64):
        raise ValueError(f"dtype must be torch.float32 or torch.float64; got {dtype}")
    for name, value, least in (("batch", batch, 1), ("repeats", repeats, 1), ("n", n, 1)):
        if isinstance(value, bool) or not isinstance(value, int) or value < least:
            raise ValueError(f"{name} must be an integer >= {least}; got {value!r}")
    steps = tuple(steps)
    if not steps or any(isinstance(s, bool) or not isinstance(s, int) or s < 2 for s in steps):
        raise ValueError(f"steps must be a non-empty sequence of integers >= 2; got {steps!r}")
    if threads is not None and (not isinstance(threads, int) or threads < 1):
        raise ValueError(f"threads must be None or an integer >= 1; got {threads!r}")
    if not dt > 0:
        raise ValueError(f"dt must be a positive number; got {dt!r}")

    previous = torch.get_num_threads()
    if threads is not None:
        torch.set_num_threads(threads)
    try:
        generator = torch.Generator().manual_seed(seed)
        system = _systems(batch, n, dtype, generator)
        rows = []
        for length in steps:
            u = torch.randn(batch, length, generator=generator, dtype=torch.float64).to(dtype)
            times: dict[str, list[float]] = {name: [] for name in _METHODS}
            for r in range(repeats + 1):
                for name, method in _METHODS.items():
                    elapsed = _pass_ms(method, system, u, dt)
                    if r > 0:  # the first pass warms caches and allocators up
                        times[name].append(elapsed)
            ms = {name: statistics.median(values) for name, values in times.items()}
            rows.append(
                DecoderTiming(
                    steps=length,
                    dtype=str(dtype).removeprefix("torch."),
                    default_ms=ms["default"],
                    fft_ms=ms["fft"],
                    scan_ms=ms["scan"],
                    loop_ms=ms["loop"],
                    speedup=ms["loop"] / ms["default"],
                    batch=batch,
                )
            )
        return rows
    finally:
        torch.set_num_threads(previous)


def format_decoder_table(rows: Sequence[DecoderTiming]) -> str:
    """A markdown table of decoder timings (forward + backward, milliseconds).

    Parameters
    ----------
    rows : sequence of DecoderTiming
        What :func:`bench_decoder` returned.

    Returns
    -------
    str
    """
    lines = [
        "| batch | steps | dtype | default: chunked (ms) | Markov + FFT (ms) | odd-even scan (ms) "
        "| per-step loop (ms) | speedup (loop / default) |",
        "|---:|---:|:---|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r.batch} | {r.steps} | {r.dtype} | {r.default_ms:.1f} | {r.fft_ms:.1f} "
            f"| {r.scan_ms:.1f} | {r.loop_ms:.1f} | {r.speedup:.1f}x |"
        )
    return "\n".join(lines)


# ----------------------------------------------------------------------------------------------
# Identification: encoder, encoder + refine, and the classical baselines, side by side
# ----------------------------------------------------------------------------------------------
def _baseline(method, y, *, dt, **kw):
    """A baseline on one step record (u = None: unit step)."""
    return method(y, None, dt, **kw)


def _run_method(call, y, y_clean, params_true, structure):
    """Time ``call`` on every record back to back, then score the estimates (see the caller)."""
    from aeid_struct.baselines import failure
    from aeid_struct.metrics import step_error

    times, steps, fails = [], [], []
    perr = {k: [] for k in params_true}
    try:  # one untimed call builds what a method caches (trace, solver)
        call(y[0])
    except Exception:
        pass
    # Time the calls back to back, then evaluate: checking an estimate between two calls
    # (CasADi inverse, simulation) evicts caches and measured up to 2.6x slower encoder calls.
    estimates = []
    for i in range(len(y)):
        t0 = time.perf_counter()
        try:
            estimates.append(call(y[i]))
        except Exception as exc:  # a baseline that throws counts as a failure
            estimates.append(exc)
        times.append(time.perf_counter() - t0)
    for i, est in enumerate(estimates):
        if isinstance(est, Exception):
            steps.append(np.inf)
            fails.append(f"exception: {est}")
            continue
        why = failure(est, structure=structure, truth_y=y_clean[i])
        fails.append(why)
        try:
            with np.errstate(all="ignore"):
                yh = est.y_hat
            s = float(step_error(y_clean[i], yh)[0]) if np.all(np.isfinite(yh)) else np.inf
        except ValueError:   # a failed method's non-finite model cannot be simulated
            s = np.inf
        steps.append(s)
        if not why:
            phys = est.physical
            for k in perr:
                if k in phys:
                    perr[k].append(100 * abs(float(phys[k]) - params_true[k][i]) /
                                   params_true[k][i])
    steps = np.asarray(steps)
    ok = np.array([not f for f in fails])
    t = np.asarray(times) * 1e3
    return {
        "step_mean": float(steps[ok].mean()) if ok.any() else float("nan"),
        "step_median": float(np.median(steps)),
        "params": {k: float(np.mean(v)) if v else float("nan") for k, v in perr.items()},
        "params_median": {k: float(np.median(v)) if v else float("nan")
                          for k, v in perr.items()},
        "failure_rate": float(1 - ok.mean()),
        "median_ms": float(np.median(t)),
        "p95_ms": float(np.percentile(t, 95)),
        "reasons": sorted({f.split(":")[0] for f in fails if f})[:5],
    }


def bench_identification(*, count: int = 500, noises=(0.0, 0.01, 0.05),
                         subsystems=("stable", "unstable"), seed: int = 2024,
                         progress: bool = True) -> dict:
    """Accuracy and speed of every method on the same records, in one run.

    For each leg subsystem and noise level, ``count`` fresh systems are drawn (seed ``seed``),
    their unit-step records simulated exactly and corrupted with white noise; every method
    identifies every record with one batch-1 call (timed); errors are measured against the
    noise-free truth. Methods: the shipped encoder, its noise-trained variant (where shipped),
    encoder + CasADi refinement (the shipped identifier's ``refine=True``, in its structure),
    n4sid (nfoursid, exact FOH conversion), least squares and the CasADi NLP from a generic
    cold start. Also the encoder's batched throughput.

    Parameters
    ----------
    count : int
        Systems per subsystem and noise level.
    noises : tuple of float
        Noise levels, standard deviation as a share of ``max|y|``.
    subsystems : tuple of str
        Leg subsystems (``"stable"``, ``"unstable"``).
    seed : int
        Seed of the systems and the noise.
    progress : bool
        Print one line per method.

    Returns
    -------
    dict
        JSON-able: ``results``, one entry per (subsystem, noise, method) with ``step_mean``
        (mean Table I step error against the noise-free truth over the records the method did
        not fail on), ``step_median`` (over all), ``params`` (mean absolute % error of k, d, m
        over non-failed records), ``failure_rate`` (exception, invalid parameters or step error
        > 0.05, see ``baselines.failure``), ``median_ms``/``p95_ms`` per identification and
        ``encoder_speedup`` (this method's median time over the encoder's, same records);
        ``throughput_per_s`` of the encoder at batch 4096, ``encoder_flops_per_record`` and
        ``matmul_peak_flops`` (``studies.roofline``: the roofline of that throughput).
    """
    from aeid_struct import baselines
    from aeid_struct.identification import load_pretrained
    from aeid_struct.studies.leg_paper import RECORDS
    from aeid_struct.studies.roofline import encoder_flops, matmul_peak
    from aeid_struct.training import LegFamily, records

    results, throughput, flops = [], {}, {}
    for sub in subsystems:
        dt, steps = RECORDS[sub]
        clean = load_pretrained(f"leg-{sub}")
        try:
            noisy = load_pretrained(f"leg-{sub}-noisy")
        except ValueError:
            noisy = None
        structure = clean.structure
        # estimates are judged in Table I's free CCF (Descartes' rule where the subsystem's
        # shipped identifier has it), the structure every method here can return: judged in
        # the leg's physics structure (c1 = 0), every n4sid model and every free-CCF
        # identifier's (the noise-trained one) failed on a noisy record
        # because c1 was not exactly 0
        judge = load_pretrained(f"leg-{sub}-ccf").structure
        inverse = LegFamily(subsystem=sub).inverse()
        for noise in noises:
            rec = records(LegFamily(subsystem=sub), count, steps=steps, dt=dt, noise=noise,
                          seed=seed + int(1000 * noise))
            truth = {k: v for k, v in rec.systems.params.items()
                     if k in inverse.name_out()}
            base = dict(structure=structure, inverse=inverse)
            methods = [("encoder", clean.identify, "")]
            if noisy is not None:
                methods.append(("encoder (noise-trained)", noisy.identify, ""))
            methods += [
                # what a user runs: the shipped identifier's refine=True, in its structure
                # (the leg's physics: c1 = 0, and a1 = 0 for the rotational leg)
                ("encoder + refine", partial(clean.identify, refine=True), "shipped"),
                ("n4sid", partial(_baseline, baselines.n4sid, dt=dt, order=2, **base), ""),
                ("least squares (cold)", partial(_baseline, baselines.least_squares, dt=dt,
                                                 **base), ""),
                ("CasADi NLP (cold)", partial(_baseline, baselines.casadi_cold, dt=dt,
                                              **base), ""),
            ]
            for name, call, start in methods:
                # at the process's threads, as a user runs them: the library's single-record
                # calls limit their own BLAS (aeid_struct.threads); the header prints the
                # settings (threads.settings())
                r = _run_method(call, rec.y, rec.y_clean, truth, judge)
                results.append({"subsystem": sub, "noise": noise, "method": name,
                                "count": count, "start": start, **r})
                if progress:
                    print(f"  {sub:8s} noise {noise:4.0%}  {name:24s} step {r['step_mean']:.2e}"
                          f"  fail {r['failure_rate']:5.1%}  {r['median_ms']:7.3f} ms",
                          flush=True)
        y = np.tile(rec.y, (max(1, 4096 // count), 1))[:4096]
        clean.identify(y)
        t0 = time.perf_counter()
        for _ in range(3):
            clean.identify(y)
        throughput[sub] = 3 * len(y) / (time.perf_counter() - t0)
        flops[sub] = encoder_flops(clean)
    for r in results:
        if r["method"].startswith("encoder") and r["method"] != "encoder":
            continue
        enc = next(e for e in results if e["subsystem"] == r["subsystem"]
                   and e["noise"] == r["noise"] and e["method"] == "encoder")
        r["encoder_speedup"] = r["median_ms"] / enc["median_ms"]
    return {"results": results, "throughput_per_s": throughput, "count": count, "seed": seed,
            "encoder_flops_per_record": flops, "matmul_peak_flops": matmul_peak()}


#: The columns of ``format_identification_table``, printed under the table.
IDENTIFICATION_LEGEND = """\
Columns:
- noise: white Gaussian noise added to each record, standard deviation as a share of the
  record's max |y|; every error is measured against the noise-free truth.
- step error: Table I step error, mean |y_hat - y| over the record with both unit-step
  responses scaled by the true response's range (dimensionless). "mean, ok": over the records
  the method did not fail on; "median, all": over every record (a failed record without a
  usable model counts as inf).
- Δk / Δd / Δm: median absolute error of the physical parameter, % of the true value, over the
  records the method did not fail on. "-": the subsystem does not contain the parameter (the
  rotational leg's G2 = (1/(m L^2))/(s^2 - g/L) does not depend on d).
- n/a (any column): every record failed, so there is nothing to average.
- failures: share of records that baselines.failure rejects, the first reason in this order:
  the method raised or reported a failure; the model is not finite; it violates Table I's
  free CCF (Descartes' sign rule where the shipped identifier has it: the structure every
  method here can return); a physical parameter is not finite and
  positive; its unit-step response has a step error above 0.05. With 20 records (--quick) one
  record is 5 %.
- median / p95 ms: wall time of one identification of one record (batch 1), at the threads
  the header names.
- baseline / encoder time: this method's median time over the plain encoder's, same records.
- encoder + refine: the shipped identifier's refine=True, the CasADi NLP in its structure
  (the leg's physics) started from its one pass. It minimises the output error, so on
  noisy records it returns a least-squares fit of the record (on most rows the cold
  baselines' answer), which is not the truth: where the record constrains a parameter weakly
  (k and m from the rotational leg's 0.5 s record) the refined parameters can be far worse
  than the encoder's although the refined step error is lower."""


def _cell(values: dict, name: str, fmt: str) -> str:
    """``values[name]`` formatted; ``-`` where the subsystem has no such parameter (absent),
    ``n/a`` where it has one but no record passed (nan)."""
    if name not in values:
        return "-"
    v = values[name]
    return "n/a" if v is None or math.isnan(v) else format(v, fmt)


def format_identification_table(bench: dict, *, legend: bool = True) -> str:
    """A markdown table of the identification benchmark.

    Parameters
    ----------
    bench : dict
        What :func:`bench_identification` returned.
    legend : bool
        Put the column definitions (``IDENTIFICATION_LEGEND``) under the table.

    Returns
    -------
    str
    """
    lines = ["| subsystem | noise | method | step error (mean, ok) | step error (median, all) "
             "| Δk % (median, ok) | Δd % | Δm % | failures | median ms | p95 ms "
             "| baseline / encoder time |",
             "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in bench["results"]:
        p = r["params_median"]
        speed = r.get("encoder_speedup")
        lines.append(
            f"| {r['subsystem']} | {r['noise']:.0%} | {r['method']} | "
            f"{_cell(r, 'step_mean', '.2e')} | {r['step_median']:.2e} | "
            f"{_cell(p, 'k', '.3f')} | {_cell(p, 'd', '.3f')} | {_cell(p, 'm', '.3f')} | "
            f"{r['failure_rate']:.1%} | {r['median_ms']:.3f} | {r['p95_ms']:.3f} | "
            f"{'' if speed is None or r['method'] == 'encoder' else f'{speed:.1f}x'} |")
    thr = ", ".join(f"{k}: {v:,.0f}/s" for k, v in bench["throughput_per_s"].items())
    lines.append(f"\nEncoder batched throughput (batch 4096): {thr}")
    peak = bench.get("matmul_peak_flops")
    for sub, per in bench.get("encoder_flops_per_record", {}).items():
        achieved = bench["throughput_per_s"][sub] * per
        lines.append(f"  {sub}: {per / 1e6:.3f} MFLOP/record (encoder), {achieved / 1e9:.2f} "
                     f"GFLOP/s achieved = {100 * achieved / peak:.1f} % of the measured fp32 "
                     f"matmul peak ({peak / 1e9:.0f} GFLOP/s, torch.mm 1024 x 1024)")
    if legend:
        lines.append("\n" + IDENTIFICATION_LEGEND)
    return "\n".join(lines)
