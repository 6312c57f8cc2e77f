"""A :class:`~symbolic.mechanism.Mechanism` as a physical structure's map: the CCF of one of its
channels (``Mechanism.channel``), or of several channels of one record (a record with several
outputs, or a decoupled input per output), of one record of several inputs moving at once (each
output the sum of its channels) or of separate experiments (one input moving in each), as a
Function of its free parameters, after an
identifiability check of those channels over the structure's box, so that a structure whose
records cannot determine a parameter is refused before any training (docs/architecture.md,
"Your own mechanism")."""

from __future__ import annotations

from collections.abc import Mapping

import casadi
import numpy as np

__all__ = ["channel_specs", "grid_specs", "is_mechanism", "mechanism_map", "mechanism_structure"]

#: Points of the box at which a channel a split record assumes absent must vanish.
PROBES = 6


def is_mechanism(value) -> bool:
    """Whether ``value`` is a ``symbolic.mechanism.Mechanism`` (by its type, imported here so
    that a plain CasADi map does not import the mechanism module).

    Parameters
    ----------
    value : object

    Returns
    -------
    bool
    """
    from symbolic.mechanism import Mechanism

    return isinstance(value, Mechanism)


def mechanism_structure(mechanism, bounds: Mapping, known: Mapping | None, channel, channels,
                        experiments, operating: dict, outputs=None, inputs=None) -> tuple:
    """``Physical(mechanism, ...)``'s map and the channels a record of several outputs is
    split by (None for one channel and for ``experiments``), its arguments checked.

    Parameters
    ----------
    mechanism : Mechanism
    bounds, known, channel, channels, experiments, operating, outputs, inputs
        As ``Physical`` takes them.

    Returns
    -------
    (casadi.Function, tuple of (output, input) or None)

    Raises
    ------
    ValueError
        ``experiments`` not a bool, or True without a mechanism's ``channels``; ``outputs``
        and ``inputs`` not given together, or beside ``channel``, ``channels`` or
        ``experiments``; and as :func:`channel_specs` and :func:`mechanism_map`.
    """
    if not isinstance(experiments, bool):
        raise ValueError(f"experiments must be True or False; got {experiments!r}")
    if outputs is not None or inputs is not None:
        if not is_mechanism(mechanism):
            raise ValueError("outputs= and inputs= read a symbolic.Mechanism's channels; a "
                             "casadi.Function map fixes them itself")
        if outputs is None or inputs is None or channel is not None or channels is not None \
                or experiments:
            raise ValueError("a record of several inputs at once is Physical(mechanism, "
                             "outputs=[...], inputs=[...]): give both, and neither channel, "
                             "channels nor experiments")
        specs = grid_specs(outputs, inputs)
        function = mechanism_map(mechanism, bounds, known, specs, operating, superposed=True)
        return function, tuple((o, i) for o, i, _ in specs)
    if experiments and (channels is None or not is_mechanism(mechanism)):
        raise ValueError("experiments=True reads a mechanism's channels=: one record per "
                         "channel, its input alone moving")
    specs = channel_specs(channel, channels, experiments)
    function = mechanism_map(mechanism, bounds, known, specs, operating, experiments)
    split = (tuple((o, i) for o, i, _ in specs) if channels is not None and not experiments
             else None)
    return function, split


def grid_specs(outputs, inputs) -> tuple[tuple, ...]:
    """The channels of one record of several inputs moving at once: every ``(output, input)``
    of ``outputs x inputs``, output after output (each output a group of ``len(inputs)``
    records, ``Physical.groups``).

    Parameters
    ----------
    outputs, inputs : sequences of distinct non-negative ints

    Returns
    -------
    tuple of (output, input, None)

    Raises
    ------
    ValueError
        Not a non-empty sequence of distinct non-negative integers (named).
    """
    for name, value in (("outputs", outputs), ("inputs", inputs)):
        ok = (not isinstance(value, (str, bytes)) and hasattr(value, "__len__")
              and len(value) >= 1 and all(isinstance(v, (int, np.integer))
                                          and not isinstance(v, bool) and v >= 0 for v in value)
              and len(set(int(v) for v in value)) == len(value))
        if not ok:
            raise ValueError(f"{name} must be a non-empty sequence of distinct non-negative "
                             f"integer indices; got {value!r}")
    return tuple((int(o), int(i), None) for o in outputs for i in inputs)


def channel_specs(channel, channels, experiments: bool = False) -> tuple[tuple, ...]:
    """The channels of ``Physical(mechanism, channel=..., channels=...)``, checked: one
    ``(output, input[, states])`` per record of the structure.

    Parameters
    ----------
    channel : tuple or None
        One channel (``(0, 0)`` where both are None).
    channels : sequence of tuples or None
        Several channels of one record, each output once; or, with ``experiments``, each
        channel a record of its own, each pair ``(output, input)`` once.
    experiments : bool
        Whether the channels are records of separate experiments (outputs may repeat).

    Returns
    -------
    tuple of (output, input, states or None)

    Raises
    ------
    ValueError
        Both given, a malformed channel (not a pair or triple, an index that is not a
        non-negative integer), an output named twice (a pair, with ``experiments``).
    """
    if channel is not None and channels is not None:
        raise ValueError("give channel (one) or channels (several), not both")
    if channels is None:
        given = [(0, 0) if channel is None else channel]
    elif isinstance(channels, (str, bytes)) or not hasattr(channels, "__len__") \
            or len(channels) < 1:
        raise ValueError(f"channels must be a non-empty sequence of (output, input) or "
                         f"(output, input, states); got {channels!r}")
    else:
        given = list(channels)
    specs = []
    for spec in given:
        if isinstance(spec, (str, bytes)) or not hasattr(spec, "__len__") \
                or len(spec) not in (2, 3):
            name = "channel" if channels is None else "channels"
            raise ValueError(f"{name} must hold (output, input) or (output, input, states); "
                             f"got {spec!r}")
        output, input, *states = spec
        if not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 0
                   for v in (output, input)):
            name = "channel" if channels is None else "channels"
            raise ValueError(f"{name} must hold non-negative integer indices (output, input); "
                             f"got {spec!r}")
        specs.append((int(output), int(input), tuple(states[0]) if states and
                      states[0] is not None else None))
    outputs = [s[0] for s in specs]
    pairs = [s[:2] for s in specs]
    if experiments and len(set(pairs)) != len(pairs):
        raise ValueError(f"channels must name each (output, input) once; got {pairs}")
    if not experiments and len(set(outputs)) != len(outputs):
        raise ValueError(f"channels must name each output once (a record's output is one "
                         f"channel's; for one record of several inputs moving at once pass "
                         f"outputs=[...], inputs=[...]; for records of separate experiments, "
                         f"one input moving in each, pass experiments=True); got outputs "
                         f"{outputs}")
    return tuple(specs)


def mechanism_map(mechanism, bounds: Mapping, known: Mapping | None, specs: tuple,
                  operating: dict, experiments: bool = False,
                  superposed: bool = False) -> casadi.Function:
    """The map of ``Physical(mechanism, ...)``: the CCF of each channel in ``specs`` as a
    Function of the parameters not in ``known``, checked identifiable over ``bounds``.

    Parameters
    ----------
    mechanism : Mechanism
    bounds : dict name -> (lo, hi)
        Every free parameter's box (``Physical``'s bounds).
    known : dict name -> float or None
        Parameters held at known values.
    specs : tuple of (output, input, states or None)
        The channels the records hold (:func:`channel_specs`).
    operating : dict
        ``u``, ``q``, ``guess`` of ``Mechanism.linearise``.
    experiments : bool
        Each channel a record of its own experiment, in which its input alone moves: a
        coupled mechanism's records need no split, and the identifiability check reads the
        channels measured (``pairs``), not every output of every input.
    superposed : bool
        The channels are every output of every input of one record in which the inputs move
        at once (:func:`grid_specs`): no split check, as each output is their sum.

    Returns
    -------
    casadi.Function
        ``'<name>_y<i>_u<j>'`` with outputs ``A, B, C, D`` for one channel;
        ``'<name>_y<i>u<j>_y<k>u<l>..'`` with ``A1, .., DR`` for ``R`` (each of the same order).

    Raises
    ------
    ValueError
        A malformed channel or operating point; bounds that are not the free parameters';
        channels of different orders; several inputs where an output also answers another
        channel's input (the record cannot be split by channel); a parameter the channels'
        records cannot determine (named, with what to fix).
    """
    from symbolic.identifiability import identifiability

    free, _ = mechanism.free(known)
    if not isinstance(bounds, Mapping) or set(bounds) != set(free):
        given = sorted(bounds) if isinstance(bounds, Mapping) else bounds
        raise ValueError(f"bounds must give every parameter of {mechanism.name} not in known "
                         f"({list(free)}); got {given!r}")
    if experiments:
        report = identifiability(mechanism, bounds, known=known,
                                 pairs=[(o, i) for o, i, _ in specs], **operating)
    else:
        if len(specs) > 1 and not superposed:
            _check_split(mechanism, specs, bounds, known, operating)
        inputs = sorted({i for _, i, _ in specs})
        outputs = list(dict.fromkeys(o for o, _, _ in specs))
        report = identifiability(mechanism, bounds, known=known, inputs=inputs,
                                 outputs=outputs, **operating)
    if not report.full:
        what = ", ".join(f"y[{o}] from u[{i}]" for o, i, _ in specs)
        raise ValueError(
            f"a record of {what} cannot determine {', '.join(report.unidentifiable)} of "
            f"{mechanism.name} (rank {report.rank} of {len(report.parameters)}); fix "
            f"{', '.join(report.fix)} with known={{...}} or measure another channel:\n{report}")
    if len(specs) == 1:
        output, input, states = specs[0]
        return mechanism.channel(output, input, states=states, known=known, **operating)
    return mechanism.channels(specs, known=known, **operating)


def _check_split(mechanism, specs, bounds, known, operating) -> None:
    """Where the channels read several inputs, each channel's output must not answer the
    other channels' inputs (a decoupled linearisation, the upright leg): a record is split by
    channel, so a coupling term would be read as noise. Checked on the Markov parameters
    ``C A^k B`` and ``D`` at points of the box."""
    inputs = sorted({i for _, i, _ in specs})
    if len(inputs) == 1:
        return
    lin = mechanism.linearise(known=known, **operating)
    rng = np.random.default_rng(0)
    names = list(lin.name_in())
    for _ in range(PROBES):
        point = {k: rng.uniform(*bounds[k]) for k in names}
        out = lin.call(point)
        A, B, C, D = (np.array(out[k]) for k in ("A", "B", "C", "D"))
        scale = np.linalg.norm(A) + 1.0
        for o, i, _ in specs:
            for j in inputs:
                if j == i:
                    continue
                markov = [D[o, j]] + [C[o] @ np.linalg.matrix_power(A / scale, k) @ B[:, j]
                                      for k in range(A.shape[0])]
                size = np.abs(C[o]).max() * np.abs(B).max() + np.abs(D).max() + 1e-300
                if np.max(np.abs(markov)) > 1e-10 * size:
                    raise ValueError(
                        f"channels read inputs {inputs}, but y[{o}] also answers u[{j}] (its "
                        f"Markov parameters do not vanish at {point}): a record of several "
                        "inputs is split by channel only where each output answers its own "
                        "input alone; for a record of several inputs moving at once pass "
                        "outputs=[...], inputs=[...] (each output the sum of its channels), "
                        "or record one input at a time (the others at rest) and pass those "
                        "records with experiments=True")
