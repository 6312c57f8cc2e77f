"""The decoder's numpy kernels (paper Eq. 10-13) for one system, without torch: Eq. 10 by one
matrix exponential (:func:`discrete_foh`), the free response's basis (:func:`free_basis`), the
convolution form of the FOH response (:func:`simulate_outputs`, the same coefficients as the
torch kernels of ``kernels.py``), and a record's response and least-squares initial state for an
estimate read where torch is not installed (:func:`simulate_numpy`,
:func:`initial_state_numpy`); the response of an output that sums the channels of several inputs
moving at once, with its initial state projected out (:func:`summed_response`). No checks: the
callers have checked their arrays.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

__all__ = ["discrete_foh", "discrete_inputs", "free_basis", "initial_state_numpy",
           "output_groups", "outputs_and_basis", "simulate_numpy", "simulate_outputs",
           "summed_response"]


def simulate_outputs(A: np.ndarray, b: np.ndarray, C: np.ndarray, d: np.ndarray, u: np.ndarray,
                     dt: float) -> np.ndarray:
    """Eq. 10-13 in numpy float64 for one system with several outputs, from rest, unchecked.

    ``y_k = t0_k u_0 + sum_{m=1}^{k} tk_{k-m} u_m`` with ``tk = (d + C gamma2, C Bd, C Phi Bd, ..)``
    and ``t0 = (d, C E, C Phi E, ..)``, the coefficients of :func:`simulate_batch` over the whole
    record (``E``, ``Bd``: :func:`foh_columns`), ``C Phi^m`` by doubling and a direct (not FFT)
    convolution, so each sample keeps its own relative accuracy. Overflow is not handled: call it
    under ``np.errstate`` and check the result.

    Parameters
    ----------
    A : (n, n) array
    b : (n,) array
    C : (r, n) array
        One output row per response wanted.
    d : (r,) array
    u : (steps,) array
        Input samples at ``t_k = k dt``, linear in between.
    dt : float, > 0

    Returns
    -------
    Y : (r, steps) array
        Row ``i`` is the response of ``(A, b, C[i], d[i])``, equal to
        :func:`~aeid_struct.simulation.simulate` to rounding.
    """
    return _outputs(discrete_foh(A, b, dt), C, d, u)[0]


def outputs_and_basis(A: np.ndarray, b: np.ndarray, C: np.ndarray, d: np.ndarray,
                      u: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`simulate_outputs` and the free response's basis it was built from, by one
    matrix exponential, for one system or a batch of systems on one input: a fit that
    projects the initial state out needs both, and its Jacobian the responses of many
    parameter points at once.

    Parameters
    ----------
    A : (..., n, n) array
    b : (..., n) array
    C : (..., r, n) array
    d : (..., r) array
    u : (steps,) array
    dt : float, > 0

    Returns
    -------
    Y : (..., r, steps) array
        The responses from rest.
    O : (..., steps, r, n) array
        ``O[k] = C Phi^k`` (:func:`free_basis`).
    """
    return _outputs(discrete_foh(A, b, dt), C, d, u)


def _outputs(discrete: tuple, C: np.ndarray, d: np.ndarray, u: np.ndarray):
    """:func:`simulate_outputs` of Eq. 10's ``(Phi, gamma1, gamma2)``: ``Y (..., r, steps)`` and
    the free response's basis ``O (..., steps, r, n)`` (``O[m] = C Phi^m``) that it was built
    from; leading axes are a batch of systems (an unbatched system runs the same operations
    as before batches were read)."""
    Phi, gamma1, gamma2 = discrete
    batch = Phi.shape[:-2]
    n, r, steps = Phi.shape[-1], C.shape[-2], u.shape[0]
    E = gamma1 - gamma2
    Bd = E + (Phi @ gamma2[..., None])[..., 0] if batch else E + Phi @ gamma2
    O = free_basis(Phi, C, steps)                              # O[m] = C Phi^m
    H = (O[..., : steps - 1, :, :].reshape(*batch, -1, n)
         @ np.stack([Bd, E], axis=-1)).reshape(*batch, steps - 1, r, 2)
    Cg = (C @ gamma2[..., None])[..., 0] if batch else C @ gamma2
    tk = np.concatenate([(d + Cg)[..., None], np.swapaxes(H[..., 0], -1, -2)], axis=-1)
    t0 = np.concatenate([d[..., None], np.swapaxes(H[..., 1], -1, -2)], axis=-1)
    Y = t0 * u[0]                                               # (..., r, steps)
    later = np.concatenate([[0.0], u[1:]])      # u_1, u_2, ..: u_0 enters through t0
    if np.any(later):
        for i in np.ndindex(*batch, r):
            Y[i] += np.convolve(tk[i], later)[:steps]
    return Y, O


def discrete_foh(A: np.ndarray, b: np.ndarray, dt: float = 1.0, intersample: str = "foh"):
    """Eq. 10 in numpy: ``Phi, gamma1, gamma2`` by one matrix exponential of
    ``[[A dt, b dt, 0], [0, 0, 1], [0, 0, 0]]`` (``scipy.linalg.expm``), for one system or a
    batch, real or complex (the complex step of ``refinement.projected`` goes through it).

    A held input (``intersample="zoh"``) is the same recursion with ``gamma2 = 0``: the FOH
    step ``x_{k+1} = Phi x_k + (gamma1 - gamma2) u_k + gamma2 u_{k+1}`` adds ``gamma2 (u_{k+1}
    - u_k)`` for the input's ramp over the interval, and the zero-order hold's is
    ``x_{k+1} = Phi x_k + gamma1 u_k`` (``gamma1 = int_0^dt e^{A s} ds b``). So every kernel
    built on these three arrays serves both holds.

    Parameters
    ----------
    A : (..., n, n) array
    b : (..., n) array
    dt : float, > 0
    intersample : {"foh", "zoh"}
        The input between samples (``records.Record.intersample``).

    Returns
    -------
    Phi : (..., n, n) array
    gamma1, gamma2 : (..., n) arrays
        ``gamma2`` zero for ``"zoh"``.

    Raises
    ------
    ValueError
        For another ``intersample``.
    """
    Phi, G1, G2 = discrete_inputs(A, b[..., None], dt, intersample)
    return Phi, G1[..., 0], G2[..., 0]


def discrete_inputs(A: np.ndarray, B: np.ndarray, dt: float = 1.0, intersample: str = "foh"):
    """Eq. 10 for several inputs: ``Phi (n, n), Gamma1 (n, m), Gamma2 (n, m)`` by one matrix
    exponential of ``[[A dt, B dt, 0], [0, 0, I], [0, 0, 0]]`` (the block form of
    :func:`discrete_foh`'s augmented matrix, one exponential for all ``m`` columns instead of
    ``m``); ``Gamma2 = 0`` for a held input (``intersample="zoh"``).

    Parameters
    ----------
    A : (..., n, n) array
        One system or a batch, real or complex.
    B : (..., n, m) array
    dt : float, > 0
    intersample : {"foh", "zoh"}

    Returns
    -------
    Phi : (..., n, n) array
    Gamma1, Gamma2 : (..., n, m) arrays

    Raises
    ------
    ValueError
        For another ``intersample``.
    """
    if intersample not in ("foh", "zoh"):
        # the one place the hold is read: a misspelt one must not pass for a held input
        raise ValueError(f"intersample must be 'foh' or 'zoh'; got {intersample!r}")
    n, m = B.shape[-2:]
    batch = np.broadcast_shapes(A.shape[:-2], B.shape[:-2])
    M = np.zeros(batch + (n + 2 * m, n + 2 * m), dtype=np.result_type(A, B, np.float64))
    M[..., :n, :n] = A * dt
    M[..., :n, n: n + m] = B * dt
    M[..., n: n + m, n + m:] = np.eye(m)
    X = scipy.linalg.expm(M)
    G1 = X[..., :n, n: n + m]
    gamma2 = X[..., :n, n + m:] if intersample == "foh" else np.zeros_like(G1)
    return X[..., :n, :n], G1, gamma2


def free_basis(Phi: np.ndarray, C: np.ndarray, steps: int) -> np.ndarray:
    """Rows ``C Phi^k`` for ``k < steps`` by doubling, ``O[k:2k] = O[0:k] Phi^k`` (one matrix
    product per level), in numpy: the free response's output basis, and the Markov parameters of
    :func:`simulate_outputs`; leading axes are a batch of systems.

    Parameters
    ----------
    Phi : (..., n, n) array
    C : (..., r, n) array
    steps : int, >= 1

    Returns
    -------
    (..., steps, r, n) array
    """
    *batch, r, n = C.shape
    O = np.empty((*batch, steps, r, n))
    O[..., 0, :, :] = C
    P, k = Phi, 1
    while k < steps:
        m = min(k, steps - k)
        O[..., k : k + m, :, :] = (O[..., :m, :, :].reshape(*batch, m * r, n)
                                   @ P).reshape(*batch, m, r, n)
        k += m
        if k < steps:
            P = P @ P
    return O


def _rows(A, b, c, d, *rest):
    """The arguments of one system or a batch as a list of per-system tuples, and whether they
    were batched."""
    A = np.asarray(A, dtype=np.float64)
    if A.ndim == 2:
        return [(A, np.asarray(b, dtype=np.float64), np.asarray(c, dtype=np.float64),
                 float(np.asarray(d)), *(None if v is None else np.asarray(v, dtype=np.float64)
                                        for v in rest))], False
    count = A.shape[0]

    def row(v, i):
        if v is None:
            return None
        v = np.asarray(v, dtype=np.float64)
        return v[i] if v.ndim and v.shape[0] == count else v
    return [(A[i], row(b, i), row(c, i), float(np.asarray(d).reshape(-1)[i]),
             *(row(v, i) for v in rest)) for i in range(count)], True


def simulate_numpy(A, b, c, d, u, dt: float, x0=None) -> np.ndarray:
    """The FOH response (Eq. 10-13) of one system or a batch from the state ``x0`` (zero where
    None), as ``simulation.simulate`` gives it for finite models, in numpy: the response an
    estimate reads where torch is not installed.

    Parameters
    ----------
    A : (n, n) or (batch, n, n) array
    b, c : (n,) or (batch, n) arrays
    d : float or (batch,) array
    u : (steps,) or (batch, steps) array
    dt : float, > 0
    x0 : (n,) or (batch, n) array, optional

    Returns
    -------
    (steps,) or (batch, steps) array
    """
    rows, batched = _rows(A, b, c, d, u, x0)
    out = []
    # one system at a time: the fallback where torch (whose batch kernel is vectorised over
    # systems) is absent; the convolution of each is the work, not the loop
    for A_, b_, c_, d_, u_, x_ in rows:
        Y, O = _outputs(discrete_foh(A_, b_, dt), c_[None], np.array([d_]), u_)
        out.append(Y[0] if x_ is None else Y[0] + O[:, 0, :] @ x_)
    return np.stack(out) if batched else out[0]


def initial_state_numpy(A, b, c, d, u, y, dt: float) -> np.ndarray:
    """The initial state of least output error (``simulation.initial_state``'s quantity) of one
    system or a batch, in numpy: ``y - forced = O x0`` by least squares, with ``O`` the rows
    ``c^T Phi^k``.

    Parameters
    ----------
    A : (n, n) or (batch, n, n) array
    b, c : (n,) or (batch, n) arrays
    d : float or (batch,) array
    u, y : (steps,) or (batch, steps) arrays
    dt : float, > 0

    Returns
    -------
    (n,) or (batch, n) array
    """
    rows, batched = _rows(A, b, c, d, u, y)
    out = []
    for A_, b_, c_, d_, u_, y_ in rows:
        Y, O = _outputs(discrete_foh(A_, b_, dt), c_[None], np.array([d_]), u_)
        out.append(np.linalg.lstsq(O[:, 0, :], y_ - Y[0], rcond=None)[0])
    return np.stack(out) if batched else out[0]


def summed_response(models: list, us: list, y: np.ndarray, dt: float, initial: bool,
                    x0: bool = False, cache: list | None = None):
    r"""The response of one output to several channels at once, ``y = sum_r G_r u_r`` plus a
    free response: each channel's exact FOH response from rest (Eq. 10-13) summed and, where
    ``initial``, the free response of least squares in the span of the channels' observable
    free responses ``c_r^T Phi_r^k`` (one channel: its own; the fitted states of minimum norm).

    Why an SVD and not a QR: the channels of one output share their poles, so their stacked
    free responses span at most ``n`` directions of their ``sum n_r`` columns, and a channel that
    does not see a mode (an output that does not answer an input) has fewer.

    Parameters
    ----------
    models : list of R tuples ``(A (P, n, n), b (P, n), c (P, n), d (P,))``
        The channels of ``P`` points (systems), e.g. the central differences of a Jacobian.
    us : list of R (steps,) arrays
        Each channel's input.
    y : (steps,) or (P, steps) array
        The measured output (read where ``initial``).
    dt : float, > 0
    initial : bool
        Project the initial state out.
    x0 : bool
        Also return each channel's fitted initial state.
    cache : list, optional
        Discretisations (Eq. 10) already computed, reused for a channel of equal ``A, b`` (the
        channels of one mechanism share them: one matrix exponential for all); appended to.

    Returns
    -------
    y_hat : (P, steps) array
        NaN rows where a response or a free response is not finite.
    states : list of R (P, n) arrays, or None
        Where ``x0`` and ``initial``: ``sum_r c_r^T Phi_r^k x0_r`` is the fitted free response.
    """
    Y, bases = 0.0, []
    cache = [] if cache is None else cache
    with np.errstate(all="ignore"):
        for (A, b, c, d), u in zip(models, us, strict=True):
            Yr, O = _outputs(_discretised(cache, A, b, dt), c[:, None], d[:, None], u)
            Y = Y + Yr[:, 0]                                         # (P, steps)
            bases.append(O[:, :, 0])                                 # (P, steps, n)
        if not initial:
            return Y, None
        O = np.concatenate(bases, axis=2) if len(bases) > 1 else bases[0]
        bad = ~np.isfinite(O).all(axis=(1, 2)) | ~np.isfinite(Y).all(axis=1)
        O[bad] = 0.0
        e = np.where(bad[:, None], 0.0, y - Y)
        # an orthonormal basis of the observable part: a channel that does not see a mode
        # (the pole's angle, the cart's position) has a free response of lower rank, and a
        # QR basis would project out an arbitrary extra direction
        U, sv, Vt = np.linalg.svd(O, full_matrices=False)
        keep = sv > max(O.shape[1:]) * np.finfo(float).eps * sv[:, :1]
        Q = U * keep[:, None, :]
        z = np.einsum("psk,ps->pk", Q, e)
        y_hat = Y + np.einsum("psk,pk->ps", Q, z)
        y_hat[bad] = np.nan
        if not x0:
            return y_hat, None
        inverse = np.divide(keep, sv, out=np.zeros_like(sv), where=keep)
        x = np.einsum("pkm,pk->pm", Vt, z * inverse)                 # (P, sum n_r)
        x[bad] = np.nan
        cuts = np.cumsum([basis.shape[2] for basis in bases])[:-1]
        return y_hat, np.split(x, cuts, axis=1)


def _discretised(cache: list, A: np.ndarray, b: np.ndarray, dt: float) -> tuple:
    """:func:`discrete_foh` of ``A, b`` at ``dt``, taken from ``cache`` where an entry has equal
    arrays (compared by value: the channels' maps build separate arrays), else computed and
    added."""
    for A_, b_, dt_, discrete in cache:
        if dt_ == dt and np.array_equal(A_, A) and np.array_equal(b_, b):
            return discrete
    discrete = discrete_foh(A, b, dt)
    cache.append((A, b, dt, discrete))
    return discrete


def output_groups(groups: tuple | None, R: int) -> list[list[int]]:
    """The records of each output, in order of their first record, where records are channels
    summed into outputs (``Physical.groups``: one output index per record); each record its
    own where ``groups`` is None.

    Parameters
    ----------
    groups : tuple of R ints or None
    R : int

    Returns
    -------
    list of lists of record indices
    """
    if groups is None:
        return [[r] for r in range(R)]
    return [[r for r in range(R) if groups[r] == g] for g in dict.fromkeys(groups)]
