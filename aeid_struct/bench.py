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

import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch

from .decoder import _simulate, _simulate_fft, _simulate_loop, _simulate_scan

__all__ = ["DecoderTiming", "bench_decoder", "format_decoder_table"]

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
    """A markdown table of ``bench_decoder`` rows (forward + backward, milliseconds)."""
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
