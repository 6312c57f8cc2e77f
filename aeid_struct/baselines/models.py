"""A structure's model ``(A, b, c, d)`` and its derivatives as numpy functions of the elements,
for the least-squares solvers; the structure's bounds and free elements.

CCF and MCF are affine in their elements, so their derivatives are constant
(:class:`AffineModel`); a ``Physical`` structure's come from CasADi's ``jacobian`` of its map
(:class:`CasadiModel`).
"""

from __future__ import annotations

import numpy as np

from aeid_struct.baselines.checks import estimate, nan_model

__all__ = ["AffineModel", "CasadiModel", "bounds", "check_structure", "finish", "free_indices",
           "linear_names", "model_of"]


def _split(v: np.ndarray, n: int):
    """``v (n^2 + 2n + 1, k)`` (``A`` row-major) -> ``A (k, n, n)``, ``b, c (k, n)``, ``d (k,)``."""
    return (v[: n * n].T.reshape(-1, n, n), v[n * n : n * n + n].T,
            v[n * n + n : n * n + 2 * n].T, v[-1])


def _fixed_vector(structure) -> np.ndarray:
    """All elements zero but the fixed ones, at their values: ``(q,)``."""
    fixed = structure.fixed_values
    return np.array([fixed.get(nm, 0.0) for nm in structure.element_names])


class AffineModel:
    """CCF and MCF: ``S(x) = S(x_0) + sum_j z_j S_j`` with ``z`` the free elements, ``x_0`` their
    zeros, so the derivatives ``S_j`` are constant.

    Parameters
    ----------
    structure : CCF or MCF
    free : (p,) int array
        Indices of the free elements (:func:`free_indices`).
    """

    def __init__(self, structure, free: np.ndarray):
        import torch

        x0 = _fixed_vector(structure)
        X = np.repeat(x0[None], 1 + len(free), axis=0)
        X[1 + np.arange(len(free)), free] += 1.0
        A, b, c, d = (t.detach().numpy() for t in structure.assemble(torch.from_numpy(X)))
        flat = np.concatenate([A.reshape(len(X), -1), b, c, d[:, None]], axis=1)
        self.free, self.n = free, structure.n
        self.base, self.grad = flat[0], flat[1:] - flat[0]
        self._derivatives = _split(self.grad.T, self.n)

    def system(self, x: np.ndarray):
        """The model at the elements ``x``.

        Parameters
        ----------
        x : (q,) array
            Every element, in ``structure.element_names`` order.

        Returns
        -------
        A : (n, n); b, c : (n,); d : float
        """
        A, b, c, d = _split((self.base + x[self.free] @ self.grad)[:, None], self.n)
        return A[0], b[0], c[0], d[0]

    def jacobian(self, x: np.ndarray):
        """The derivatives of the model with respect to the free elements (constant).

        Parameters
        ----------
        x : (q,) array

        Returns
        -------
        dA : (p, n, n); db, dc : (p, n); dd : (p,)
        """
        return self._derivatives


class CasadiModel:
    """Physical: ``(A, b, c, d)`` and its Jacobian from the structure's CasADi map.

    Parameters
    ----------
    structure : Physical
    free : (p,) int array
        Indices of the free elements (:func:`free_indices`).
    """

    def __init__(self, structure, free: np.ndarray):
        import casadi

        f = structure.function
        x = casadi.MX.sym("x", structure.q)
        out = f.call({nm: x[i] for i, nm in enumerate(f.name_in())})
        flat = casadi.vertcat(*(casadi.vec(out[k]) for k in "ABCD"))
        self.F = casadi.Function("system_jacobian", [x], [flat, casadi.jacobian(flat, x)])
        self.free, self.n = free, structure.n

    def _split(self, v: np.ndarray):
        """``v (n^2 + 2n + 1, k)`` in CasADi's column-major order -> ``A (k, n, n)``, ..."""
        n = self.n
        A = v[: n * n].T.reshape(-1, n, n).transpose(0, 2, 1)
        return A, v[n * n : n * n + n].T, v[n * n + n : n * n + 2 * n].T, v[-1]

    def system(self, x: np.ndarray):
        """The model at the elements ``x``.

        Parameters
        ----------
        x : (q,) array

        Returns
        -------
        A : (n, n); b, c : (n,); d : float
        """
        flat, _ = self.F(x)
        A, b, c, d = self._split(np.array(flat))
        return A[0], b[0], c[0], d[0]

    def jacobian(self, x: np.ndarray):
        """The derivatives of the model with respect to the free elements at ``x``.

        Parameters
        ----------
        x : (q,) array

        Returns
        -------
        dA : (p, n, n); db, dc : (p, n); dd : (p,)
        """
        _, J = self.F(x)
        return self._split(np.array(J)[:, self.free])


def check_structure(structure) -> None:
    """Raise unless ``structure`` is a CCF, MCF or Physical.

    Parameters
    ----------
    structure : object

    Raises
    ------
    ValueError
        Naming what came.
    """
    from aeid_struct.structures import Structure

    if not isinstance(structure, Structure):
        raise ValueError(f"structure must be a CCF, MCF or Physical; got "
                         f"{type(structure).__name__}")


def model_of(structure, free: np.ndarray):
    """The numpy model of a structure (:class:`AffineModel` or :class:`CasadiModel`).

    Parameters
    ----------
    structure : CCF, MCF or Physical
    free : (p,) int array
        Indices of the free elements.

    Returns
    -------
    AffineModel or CasadiModel

    Raises
    ------
    ValueError
        For another kind of structure.
    """
    from aeid_struct.structures import CCF, MCF, Physical, Structure

    if isinstance(structure, (CCF, MCF)):
        return AffineModel(structure, free)
    if isinstance(structure, Physical):
        return CasadiModel(structure, free)
    kind = type(structure).__name__ if isinstance(structure, Structure) else "not a Structure"
    raise ValueError(f"structure must be a CCF, MCF or Physical; got {structure!r} ({kind})")


def bounds(structure) -> tuple[np.ndarray, np.ndarray]:
    """Closed bounds of every element: ``Structure.element_bounds()`` (the closure of each
    constraint map's range; open MCF sets shrunk by 1e-8), fixed elements at their value.

    Parameters
    ----------
    structure : Structure

    Returns
    -------
    lo, hi : (q,) arrays
    """
    pairs = [structure.element_bounds()[nm] for nm in structure.element_names]
    return np.array([p[0] for p in pairs], float), np.array([p[1] for p in pairs], float)


def linear_names(structure) -> list[str]:
    """The free elements the response is linear in: ``c_i`` and ``d`` of CCF and MCF.

    Parameters
    ----------
    structure : Structure

    Returns
    -------
    list of str
    """
    from aeid_struct.structures import Physical

    if isinstance(structure, Physical):
        return []
    fixed = structure.fixed_values
    return [nm for nm in structure.element_names if nm not in fixed
            and (nm == "d" or (nm[0] == "c" and nm[1:].isdigit()))]


def free_indices(structure) -> np.ndarray:
    """Indices of the free elements in the element order.

    Parameters
    ----------
    structure : Structure

    Returns
    -------
    (p,) int array
    """
    fixed = structure.fixed_values
    return np.array([i for i, nm in enumerate(structure.element_names) if nm not in fixed],
                    dtype=int)


def finish(structure, model, names, x, y, u, dt, start_time, info, source):
    """The estimate of optimised elements ``x``, or a failed one where they are not finite.

    Parameters
    ----------
    structure : Structure
    model : AffineModel or CasadiModel
    names : sequence of str
        The structure's element names.
    x : (q,) array
    y, u : (steps,) arrays
    dt : float
    start_time : float
        ``time.perf_counter()`` when the method began.
    info : dict
    source : object
        What ``Estimate.physical`` maps.

    Returns
    -------
    Estimate
    """
    system = model.system(x)
    if not (np.all(np.isfinite(x)) and all(np.all(np.isfinite(m)) for m in system)):
        return estimate(nan_model(structure.n), {}, y, u, dt, start_time,
                        {**info, "failed": True, "reason": "non-finite elements"}, None)
    return estimate(system, dict(zip(names, x.tolist(), strict=True)), y, u, dt, start_time,
                    info, source)
