r"""Does the record determine every mode of its model? Lightly damped modes where the record
holds only noise.

An output-error fit of order ``n`` to a record whose input carries no energy near some
frequency has directions the data do not fix: it can place a lightly damped pair there, which
takes up the largest component of the noise through the initial state, with whatever gain
through the input. On the record the model fits as well as any other; on an input that does
reach that frequency its response is the resonance's, and nothing in the record says how large.

A pair ``lambda = sigma +- j omega`` of the model ``G(s) = C (sI - A)^{-1} B + D`` is **not
determined** by its records where all three hold:

    zeta = -sigma / |lambda| < ZETA                                       (lightly damped)
    snr^2 = sum_band ||Y(w_l)||^2 / (n_band e_bin) < SNR^2               (the measured output
            holds no more than noise in the pair's band |w_l - omega| <= max(3 |sigma|, 2 w_1))
    ||G(j omega)||_2 > GAIN g_u,  g_u^2 = sum_l ||G(j w_l) U(w_l)||^2 / sum_l ||U(w_l)||^2
            (its resonance is GAIN times the model's gain where the input is)

``Y, U`` the DFTs of each record's de-meaned, Hann-tapered output and input at ``w_l = 2 pi l /
(N dt)``, summed over the records; ``e_bin`` the residual's energy per bin, taken white
(``||y - yhat||^2`` spread over the bins by Parseval). Why the measured output and not the
pair's own share of the model's output: such pairs come with huge residues that cancel against
the other modes', so the modal split says nothing. Why the taper: the rectangular window's
leakage from a low-frequency input, times a resonance of gain ``1e5``, reads as output the
record never had. A lightly damped plant whose record shows its ringing (a step, a PRBS) is
determined: its band holds the ringing, far above the noise.
"""

from __future__ import annotations

import numpy as np

__all__ = ["GAIN", "SNR", "ZETA", "unexcited_modes"]

#: Damping ratio below which a pair is lightly damped (resonance peak ``~ 1 / (2 zeta)``).
ZETA = 0.05
#: The measured output's RMS in a pair's band, relative to the residual's, below which the record
#: holds nothing there but noise.
SNR = 3.0
#: Peak gain, relative to the model's gain where the input is, above which an undetermined
#: pair is reported.
GAIN = 10.0


def unexcited_modes(A, B, C, D, outputs, inputs, residual: float, dt: float) -> list[dict]:
    """The lightly damped pairs of a model that its records do not determine (module
    docstring).

    Parameters
    ----------
    A : (n, n) array
    B : (n, m) array
    C : (p, n) array
    D : (p, m) array
        The model, in the records' time unit.
    outputs : sequence of (N_r, p) arrays
    inputs : sequence of (N_r, m) arrays
        Each record's output and input (the samples the model was fitted on).
    residual : float
        ``||y - yhat||^2`` summed over every fitted sample of every record and output, in the
        outputs' units.
    dt : float
        Sample time.

    Returns
    -------
    list of dict
        One per pair not determined (upper half plane), each ``{"pole": complex (1 / time
        unit), "damping": zeta, "snr": sqrt(E_y / E_e) in its band, "gain": ||G(j omega)|| /
        g_u}``; empty where every mode is determined.
    """
    A, B, C, D = (np.asarray(M, dtype=np.float64) for M in (A, B, C, D))
    if not np.all(np.isfinite(A)):
        return []
    lam = np.linalg.eigvals(A)
    pairs = np.flatnonzero((lam.imag > 0) & (-lam.real < ZETA * np.abs(lam)))
    if pairs.size == 0:
        return []
    spectra = _spectra(outputs, inputs, residual, dt)
    g_u = _input_gain(A, B, C, D, spectra)
    if g_u is None:
        return []
    found = []
    for k in pairs:
        band_y, band_noise = 0.0, 0.0
        for w, _, power, noise in spectra:
            band = np.abs(w - lam[k].imag) <= max(3.0 * abs(lam[k].real), 2.0 * w[1])
            band_y += float(np.sum(power[band]))
            band_noise += noise * int(np.sum(band))
        peak = np.linalg.norm(_response(A, B, C, D, np.array([lam[k].imag]))[0], 2)
        gain = peak / g_u if g_u > 0 else np.inf
        snr = np.sqrt(band_y / band_noise) if band_noise > 0 else np.inf
        if snr < SNR and gain > GAIN:
            found.append({"pole": complex(lam[k]), "damping": float(-lam[k].real / abs(lam[k])),
                          "snr": float(snr), "gain": float(gain)})
    return found


def _spectra(outputs, inputs, residual: float, dt: float) -> list[tuple]:
    """Per record ``(w (L,), U (L, m), ||Y||^2 (L,), e_bin)``: the frequencies, the tapered
    input's DFT, the tapered output's power per bin and the residual's energy per bin."""
    samples = sum(np.shape(u)[0] for u in inputs)
    out = []
    for y, u in zip(outputs, inputs, strict=True):
        N = np.shape(u)[0]
        u = np.asarray(u, dtype=np.float64).reshape(N, -1)
        y = np.asarray(y, dtype=np.float64).reshape(N, -1)
        # a Hann taper: the rectangular window's leakage (1 / f) from a low-frequency input
        # reads as energy at every frequency, and a resonance of gain 1e5 turns it into output
        taper = np.hanning(N)[:, None]
        U = np.fft.rfft(taper * (u - u.mean(axis=0)), axis=0)           # (L, m)
        Y = np.fft.rfft(taper * (y - y.mean(axis=0)), axis=0)           # (L, p)
        w = 2.0 * np.pi * np.arange(U.shape[0]) / (N * dt)
        # the residual's energy per bin, taken white: its share of ``residual`` (Parseval,
        # one side, tapered)
        noise = 0.5 * N * float(np.mean(taper ** 2)) * residual * N / samples / U.shape[0]
        out.append((w, U, np.sum(np.abs(Y) ** 2, axis=1), noise))
    return out


def _input_gain(A, B, C, D, spectra) -> float | None:
    """``g_u`` of the module docstring (None where the inputs carry no energy). A record of
    more than :data:`BANDS` bins is summed in that many bands of its cross-spectral matrix
    ``S_b = sum_l U(w_l) U(w_l)^H``, ``G`` taken at each band's centre: ten million samples
    would otherwise be five million solves."""
    top, bottom = 0.0, 0.0
    for w, U, _, _ in spectra:
        edges = np.unique(np.linspace(0, w.shape[0], min(w.shape[0], BANDS) + 1).astype(int))
        m = U.shape[1]
        S = np.empty((edges.shape[0] - 1, m, m), dtype=np.complex128)
        for i in range(m):
            for j in range(m):
                S[:, i, j] = np.add.reduceat(U[:, i] * U[:, j].conj(), edges[:-1])
        centre = 0.5 * (w[edges[:-1]] + w[edges[1:] - 1])
        G = _response(A, B, C, D, centre)                                # (K, p, m)
        top += float(np.real(np.einsum("kpi,kij,kpj->", G, S, G.conj())))
        bottom += float(np.real(np.einsum("kii->", S)))
    return np.sqrt(top / bottom) if bottom > 0.0 else None


#: Bands of the cross-spectral matrix at most, per record, in :func:`_input_gain`.
BANDS = 4096


def _response(A, B, C, D, w) -> np.ndarray:
    """``G(j w) = C (j w - A)^{-1} B + D``, ``(L, p, m)``, by solves in blocks of frequencies
    (not the modal form: the modes of an over-fitted model can be near-defective, their
    residues huge and cancelling)."""
    n = A.shape[0]
    out = np.empty((w.shape[0],) + D.shape, dtype=np.complex128)
    for first in range(0, w.shape[0], BLOCK):
        part = w[first : first + BLOCK]
        M = 1j * part[:, None, None] * np.eye(n) - A
        out[first : first + BLOCK] = C @ np.linalg.solve(M, np.broadcast_to(
            B, (part.shape[0],) + B.shape)) + D
    return out


#: Frequencies per block of solves (bounds the working memory on a long record).
BLOCK = 4096
