"""The bad-input catalogue of the surfaces for any system (issue 21): ``ae.Record``,
``ae.identify``, ``ae.compare``, the baselines on records, identifier heads, generic identifier
files, ``aeid-struct identify --order`` and ``train-generic``.

The cases use the catalogue's :class:`~catalogue.Case` and are graded by its rules
(``tests/catalogue.py``; ``python tests/catalogue.py --area record identify-any ...`` prints
them). The shared record is issue 21's: ``y = 2 / (s^2 + 2 s + 5) u`` with ``u`` a +-1 PRBS, a
3-sample input delay, an offset of 1.7, ``dt = 0.05``, 600 samples, simulated by
python-control (``forced_response`` holds the input linear between samples, the library's
first-order hold), so the exact answer is known: poles ``-1 +- 2j``, delay 3, fit 100 %.
"""

from __future__ import annotations

import functools
import json

import numpy as np
from catalogue import Case, cli

N, DT, DELAY, OFFSET = 600, 0.05, 3, 1.7
TRUE_POLES = np.array([-1.0 + 2.0j, -1.0 - 2.0j])


@functools.cache
def data(numerator: tuple = (2.0,), steps: int = N, noise: float = 0.0):
    """``(y, u)`` of ``numerator / (s^2 + 2 s + 5)``, the PRBS delayed by 3 samples, offset
    1.7, by python-control."""
    import control

    rng = np.random.default_rng(21)
    u = np.repeat(rng.choice([-1.0, 1.0], steps // 5 + 1), 5)[:steps]
    delayed = np.concatenate([np.zeros(DELAY), u[:-DELAY]])
    t = np.arange(steps) * DT
    y = control.forced_response(control.tf(list(numerator), [1.0, 2.0, 5.0]), t,
                                delayed).outputs + OFFSET
    y = y + noise * np.std(y) * rng.standard_normal(steps)
    return y, u


def rec(**kw):
    import aeid_struct as ae
    y, u = data()
    return ae.Record(y, u, DT, **kw)


def honest(est, record=None) -> bool:
    """The estimate's fit is its returned model's own (``ae.compare``: x0 and offset fitted)."""
    import aeid_struct as ae
    other = ae.compare(est, rec() if record is None else record)
    return bool(abs(other.fit - est.fit) < 0.5)


def exact(est, rtol=1e-4) -> bool:
    """Poles -1 +- 2j, delay 3, fit above 99.99 % and honest."""
    poles = np.sort_complex(np.linalg.eigvals(np.asarray(est.A)))
    return (bool(np.allclose(poles, np.sort_complex(TRUE_POLES), rtol=rtol))
            and est.delay == DELAY and est.fit > 99.99 and honest(est))


def scaled_exact(est, gain: float) -> bool:
    """Exact poles and delay, and the DC gain ``gain * 0.4``."""
    poles = np.sort_complex(np.linalg.eigvals(np.asarray(est.A)))
    A, b, c, d = (np.asarray(v, dtype=np.float64) for v in (est.A, est.b, est.c, est.d))
    dc = float(d - c @ np.linalg.solve(A, b))
    return (bool(np.allclose(poles, np.sort_complex(TRUE_POLES), rtol=1e-4))
            and est.delay == DELAY and est.fit > 99.99
            and bool(np.isclose(dc, 0.4 * gain, rtol=1e-4)))


def dc_exact(est, gain: float, rtol: float) -> bool:
    """A baseline's estimate: poles -1 +- 2j and DC gain ``0.4 gain`` to ``rtol``, fit above
    99.99 % (the record given without its delay)."""
    A, b, c, d = (np.asarray(v, dtype=np.float64) for v in (est.A, est.b, est.c, est.d))
    poles = np.sort_complex(np.linalg.eigvals(A))
    dc = float(d - c @ np.linalg.solve(A, b))
    return (not est.info["failed"] and est.info["fit"] > 99.99
            and bool(np.allclose(poles, np.sort_complex(TRUE_POLES), rtol=rtol))
            and bool(np.isclose(dc, 0.4 * gain, rtol=rtol)))


def _identify(**kw):
    import aeid_struct as ae
    return ae.identify(rec(), **kw)


def _record() -> list[Case]:
    import aeid_struct as ae
    area = "record"
    y, u = data()
    return [
        Case(area, "several outputs", lambda x: ae.Record(np.stack([y, y, y], 1), u, DT),
             raises=None, check=lambda r: (r.outputs, r.inputs, r.Y.shape) == (3, 1, (N, 3))),
        Case(area, "several inputs through n4sid", lambda x: ae.baselines.n4sid(
            ae.Record(y, np.stack([u, np.roll(u, 37)], 1), DT, delay=DELAY), order=2),
             raises=None, check=lambda e: e.B.shape == (2, 2) and e.C.shape == (1, 2)
             and bool(np.all(np.asarray(e.fit) > 99.0))),
        Case(area, "a column y is one output", lambda x: ae.Record(y[:, None], u, DT),
             raises=None, check=lambda r: r.y.shape == (N,) and bool(np.all(r.y == y))),
        Case(area, "dt zero", lambda x: ae.Record(y, u, 0.0),
             match=r"^dt must be a positive finite number; got 0.0"),
        Case(area, "dt string", lambda x: ae.Record(y, u, "0.05"),
             match=r"^dt must be a positive finite number; got '0.05'"),
        Case(area, "delay beyond the record", lambda x: ae.Record(y, u, DT, delay=600),
             match=r"^delay must be >= 0 and < steps = 600; got 600"),
        Case(area, "NaN in u", lambda x: ae.Record(y, np.where(np.arange(N) == 7, np.nan, u),
                                                   DT),
             match=r"^u must be finite; got nan at sample 7"),
        # several channels: the sample, then the channel (it said "record 7, sample 1")
        Case(area, "NaN in one output of several",
             lambda x: ae.Record(np.stack([y, np.where(np.arange(N) == 7, np.nan, y)], 1), u,
                                 DT),
             match=r"^y must be finite; got nan at sample 7, output 1$"),
        Case(area, "u shorter", lambda x: ae.Record(y, u[:-1], DT),
             match=r"^u must have as many samples as y \(600\); got 599"),
    ]


def _identify_any() -> list[Case]:
    import aeid_struct as ae
    area = "identify-any"
    y, u = data()
    y2, _ = data((1.0, 2.0))
    constant = r"^u is constant over the whole record: with a free initial state and offset"
    return [
        Case(area, "the plain record is exact", lambda x: _identify(order=2), raises=None,
             check=exact),
        Case(area, "tiny output 1e-200", lambda x: ae.identify(ae.Record(y * 1e-200, u, DT),
                                                               order=2),
             raises=None, check=lambda e: scaled_exact(e, 1e-200)),
        Case(area, "huge output 1e200", lambda x: ae.identify(ae.Record(y * 1e200, u, DT),
                                                              order=2),
             raises=None, check=lambda e: scaled_exact(e, 1e200)),
        Case(area, "huge input 1e200", lambda x: ae.identify(ae.Record(y, u * 1e200, DT),
                                                             order=2),
             raises=None, check=lambda e: scaled_exact(e, 1e-200)),
        Case(area, "tiny input 1e-300 (one pass)", lambda x: ae.identify(
            ae.Record(y, u * 1e-300, DT), order=2, refine=False),
             raises=None, check=lambda e: scaled_exact(e, 1e300)),
        Case(area, "gain beyond float64", lambda x: ae.identify(
            ae.Record(y * 1e300, u * 1e-300, DT), order=2),
             match=r"^y and u: the gain of this record .* makes a model that float64 cannot "
                   r"hold"),
        Case(area, "refine a string", lambda x: _identify(order=2, refine="no"),
             match=r"^refine must be True or False; got 'no'"),
        Case(area, "classical a string", lambda x: _identify(order=2, classical="no"),
             match=r"^classical must be True or False; got 'no'"),
        Case(area, "fixed structure, unknown delay", lambda x: _identify(
            structure=ae.CCF(2).fixed(c1=0.0)), raises=None, check=exact),
        Case(area, "fixed element the data contradict: honest fit", lambda x: ae.identify(
            ae.Record(y2, u, DT), structure=ae.CCF(2).fixed(c1=0.0), refine=False),
             raises=None, check=lambda e: honest(e, ae.Record(y2, u, DT)) and e.fit < 90),
        Case(area, "max_delay beyond the record", lambda x: _identify(order=2,
                                                                      max_delay=10 ** 6),
             match=r"^max_delay must leave at least 16 samples after the delay \(twice the 8 "
                   r"parameters of an order-2 model\): at most 584 for this record of 600 "
                   r"samples; got 1000000"),
        Case(area, "known delay beyond what the model needs", lambda x: _identify(order=2,
                                                                                  delay=590),
             match=r"^delay must leave at least 16 samples after it \(twice the 8 parameters "
                   r"of an order-2 model\): at most 584 for this record of 600 samples; got 590"),
        Case(area, "max_delay at the limit, noisy record", lambda x: ae.identify(
            ae.Record(data(noise=0.05)[0], u, DT), order=2, max_delay=344),
             raises=None, check=lambda e: abs(e.delay - DELAY) <= 1 and honest(
                 e, ae.Record(data(noise=0.05)[0], u, DT)) and bool(np.allclose(
                     np.sort_complex(np.linalg.eigvals(e.A)), np.sort_complex(TRUE_POLES),
                     rtol=0.02))),
        Case(area, "y constant", lambda x: ae.identify(ae.Record(np.full(N, 1.7), u, DT),
                                                       order=2),
             match=r"^y is constant \(every sample is 1.7\): a constant output says nothing"),
        Case(area, "u constant", lambda x: ae.identify(ae.Record(y, np.ones(N), DT), order=2),
             match=constant),
        Case(area, "dt 1e-200", lambda x: ae.identify(ae.Record(y, u, 1e-200), order=2),
             match=r"^dt must give an order-2 model that float64 can hold: with dt = 1e-200 "),
        Case(area, "dt 1e200", lambda x: ae.identify(ae.Record(y, u, 1e200), order=2),
             match=r"^dt must give an order-2 model that float64 can hold: with dt = 1e\+200 "),
        Case(area, "dt 1e-6 is representable", lambda x: ae.identify(ae.Record(y, u, DT * 1e-6),
                                                                     order=2),
             raises=None, check=lambda e: bool(np.allclose(
                 np.sort_complex(np.linalg.eigvals(e.A)) * 1e-6,
                 np.sort_complex(TRUE_POLES), rtol=1e-4))),
        Case(area, "identifier by name", lambda x: _identify(order=2, identifier="generic-2"),
             raises=None, check=exact),
        Case(area, "identifier unknown name", lambda x: _identify(order=2,
                                                                  identifier="generic-9"),
             match=r"^identifier: name_or_path must be one of \['generic-1'"),
        Case(area, "identifier not an identifier", lambda x: _identify(order=2, identifier=3),
             match=r"^identifier must be a generic identifier \(ae.load_generic\), its name or "
                   r"file, or a dict order -> identifier; got int"),
        Case(area, "identifier of another order", lambda x: _identify(
            order=3, identifier="generic-2"),
             match=r"^identifier must be a generic identifier of order 3"),
        Case(area, "order zero", lambda x: _identify(order=0),
             match=r"^order must be None \(selected\) or an integer >= 1; got 0"),
        Case(area, "structure a string", lambda x: _identify(order=2, structure="modal"),
             match=r"^structure must be 'ccf', 'mcf' or a Structure; got 'modal'"),
        Case(area, "record too short", lambda x: ae.identify(ae.Record(y[:15], u[:15], DT),
                                                             order=2),
             match=r"^the record has 15 samples; a model of order 2 needs at least 16 \(twice "
                   r"its 8 fitted parameters\)"),
        Case(area, "record a 4-tuple", lambda x: ae.identify((y, u, DT, 0), order=2),
             match=r"^record must be a Record, a \(y, u\) or \(y, u, dt\) tuple"),
        Case(area, "tiny output, c1 = 0 fixed (zero gain element)", lambda x: ae.identify(
            ae.Record(y * 1e-200, u, DT), structure=ae.CCF(2).fixed(c1=0.0)),
             raises=None, check=lambda e: scaled_exact(e, 1e-200)),
        Case(area, "tiny output, c0 fixed (gain kept)", lambda x: ae.identify(
            ae.Record(y * 1e-200, u, DT), structure=ae.CCF(2).fixed(c0=2e-200)),
             match=r"^y and u: a structure with fixed gain elements keeps the record's gain, "
                   r"and max\|y\| = .* and max\|u\| = 1 are too far apart for float64"),
        Case(area, "both tiny, c0 fixed (gain kept, scaled alike)", lambda x: ae.identify(
            ae.Record(y * 1e-200, u * 1e-200, DT), structure=ae.CCF(2).fixed(c0=2.0)),
             raises=None, check=lambda e: scaled_exact(e, 1.0)),
        Case(area, "tiny output in the modal form", lambda x: ae.identify(
            ae.Record(y * 1e-200, u, DT), order=2, structure="mcf"),
             raises=None, check=lambda e: scaled_exact(e, 1e-200)),
        Case(area, "tiny output, order selected", lambda x: ae.identify(
            ae.Record(y * 1e-200, u, DT), refine=False),
             raises=None, check=lambda e: e.A.shape == (2, 2) and scaled_exact(e, 1e-200)),
        Case(area, "max_delay a float", lambda x: _identify(order=2, max_delay=3.5),
             match=r"^max_delay must be None or an integer >= 0; got 3.5"),
        Case(area, "300 samples, default max_delay", lambda x: ae.identify(
            ae.Record(y[:300], u[:300], DT), order=2),
             raises=None, check=lambda e: exact(e) and e.info["max_delay"] == 10),
        Case(area, "exactly the window, default max_delay", lambda x: ae.identify(
            ae.Record(y[:256], u[:256], DT), order=2),
             raises=None, check=lambda e: e.info["max_delay"] == 10 and e.delay == DELAY
             and honest(e, ae.Record(y[:256], u[:256], DT))),
        Case(area, "shorter than the window, max_delay capped by the model", lambda x: (
            ae.identify(ae.Record(y[:64], u[:64], DT), order=2)),
             raises=None, check=lambda e: e.info["max_delay"] == 10 and e.delay == DELAY
             and e.fit > 99.99 and honest(e, ae.Record(y[:64], u[:64], DT))),
        Case(area, "negative delay", lambda x: _identify(order=2, delay=-1),
             match=r"^delay must be None \(unknown\) or an integer number of samples in "
                   r"\[0, 598\]; got -1"),
        Case(area, "iterations negative", lambda x: _identify(order=2, iterations=-1),
             match=r"^iterations must be an integer >= 0"),
        Case(area, "method unknown", lambda x: _identify(order=2, method="lbfgs"),
             match=r"^method must be one of 'auto', 'separable', 'casadi'; got 'lbfgs'"),
        Case(area, "identifier dict with a name", lambda x: _identify(
            order=2, identifier={2: "generic-2"}),
             match=r"^identifier must be a generic identifier .*; got str"),
        Case(area, "record shifted by offsets only (input offset 1e6)", lambda x: ae.identify(
            ae.Record(y, u + 1e6, DT), order=2),
             raises=None, check=lambda e: bool(np.allclose(
                 np.sort_complex(np.linalg.eigvals(e.A)), np.sort_complex(TRUE_POLES),
                 rtol=1e-3)) and e.delay == DELAY),
        Case(area, "output level 1e8 above its variation", lambda x: ae.identify(
            ae.Record(y + 1e8, u, DT), order=2),
             raises=None, check=lambda e: bool(np.allclose(
                 np.sort_complex(np.linalg.eigvals(e.A)), np.sort_complex(TRUE_POLES),
                 rtol=1e-5)) and e.delay == DELAY and bool(np.isclose(e.offset, 1e8 + OFFSET,
                                                                       rtol=1e-12))),
        Case(area, "MIMO y through identify", lambda x: ae.identify(
            (np.stack([y, y], 1), u, DT), order=2),
             raises=None, check=lambda e: e.C.shape == (2, 2) and bool(np.allclose(
                 np.sort_complex(np.linalg.eigvals(e.A)), np.sort_complex(TRUE_POLES),
                 rtol=1e-5)) and np.array_equal(e.delay, DELAY)),
    ]


def _compare() -> list[Case]:
    import control

    import aeid_struct as ae
    area = "compare"
    y, u = data()
    G = control.tf([2.0], [1.0, 2.0, 5.0])

    @functools.cache
    def est():
        return ae.identify(rec(), order=2)

    def half():      # every second sample: dt 0.1, the delay 0.15 s is 1.5 samples
        return ae.Record(y[::2], u[::2], 2 * DT)

    def finer():     # the same signals read at dt 0.025: the delay 0.15 s is 6 samples
        import aeid_struct as ae2
        t = np.arange(2 * N) * DT / 2
        uu = np.interp(t, np.arange(N) * DT, u)
        delayed = np.interp(t - DELAY * DT, np.arange(N) * DT, u, left=0.0)
        yy = control.forced_response(G, t, delayed).outputs + OFFSET
        return ae2.Record(yy, uu, DT / 2)

    def integrated():  # 1/s driven by an input on a level: a ramp no x0 or offset absorbs
        t = np.arange(N) * DT
        return ae.Record(control.forced_response(control.tf([1.0], [1.0, 0.0]), t,
                                                 u + 10.0).outputs, u + 10.0, DT)

    return [
        Case(area, "delay carried through seconds", lambda x: ae.compare(est(), finer()),
             raises=None, check=lambda c: c.delay == 2 * DELAY and c.fit > 99.9),
        Case(area, "delay not on a sample", lambda x: ae.compare(est(), half()),
             match=r"^the estimate's delay \(3 samples of dt = 0.05, 0.15 time units\) is 1.5 "
                   r"samples of this record \(dt = 0.1\), not a whole number: pass delay= "),
        Case(area, "discrete StateSpace", lambda x: ae.compare(
            control.ss(control.c2d(G, DT, method="foh")), rec(), delay=3),
             match=r"^estimate_or_model is a discrete-time system \(dt = 0.05\); compare "
                   r"simulates continuous-time models"),
        Case(area, "discrete TransferFunction", lambda x: ae.compare(
            control.c2d(G, DT, method="foh"), rec(), delay=3),
             match=r"^estimate_or_model is a discrete-time system \(dt = 0.05\)"),
        Case(area, "continuous TransferFunction", lambda x: ae.compare(G, rec(), delay=3),
             raises=None, check=lambda c: c.fit > 99.999),
        Case(area, "continuous StateSpace", lambda x: ae.compare(control.ss(G), rec(),
                                                                 delay=3),
             raises=None, check=lambda c: c.fit > 99.999),
        Case(area, "tiny record, its own estimate", lambda x: ae.compare(
            ae.identify(ae.Record(y * 1e-200, u, DT), order=2), ae.Record(y * 1e-200, u, DT)),
             raises=None, check=lambda c: c.fit > 99.99 and bool(np.isclose(
                 c.y_offset, OFFSET * 1e-200, rtol=1e-6))),
        Case(area, "huge input, the true model scaled", lambda x: ae.compare(
            control.tf([2e-200], [1.0, 2.0, 5.0]), ae.Record(y, u * 1e200, DT), delay=3),
             raises=None, check=lambda c: c.fit > 99.999),
        Case(area, "a gain float64 cannot hold on this record", lambda x: ae.compare(
            control.tf([1e300], [1.0, 2.0, 5.0]), ae.Record(y * 1e-300, u * 1e10, DT)),
             match=r"^estimate_or_model: its gain .* leaves float64"),
        Case(area, "input level 1e6 +- 1, the true model", lambda x: ae.compare(
            G, ae.Record(y, u + 1e6, DT), delay=3),
             raises=None, check=lambda c: c.fit > 99.99999 and bool(np.isclose(
                 c.y_offset, OFFSET - 0.4e6, rtol=1e-9))),
        Case(area, "an integrator on an input level (the level kept)", lambda x: ae.compare(
            control.tf([1.0], [1.0, 0.0]), integrated()),
             raises=None, check=lambda c: c.fit > 99.999),
        Case(area, "a string model", lambda x: ae.compare("G", rec()),
             match=r"^estimate_or_model must be an Estimate, a continuous-time "
                   r"control.StateSpace or TransferFunction, or a tuple \(A, b, c, d\); got str"),
        Case(area, "MIMO StateSpace", lambda x: ae.compare(control.ss(
            [[-1.0]], [[1.0, 1.0]], [[1.0]], [[0.0, 0.0]]), rec()),
             match=r"^estimate_or_model must have the record's 1 output\(s\) and 1 input\(s\)"),
        Case(area, "non-finite model", lambda x: ae.compare(
            (np.array([[np.nan]]), [1.0], [1.0], 0.0), rec()),
             match=r"^the model \(A, b, c, d\) must be finite"),
        Case(area, "delay beyond the record", lambda x: ae.compare(G, rec(), delay=599),
             match=r"delay must be None \(unknown\) or an integer number of samples in "
                   r"\[0, 598\]; got 599"),
    ]


def _baselines_record() -> list[Case]:
    import aeid_struct as ae
    area = "baselines-rec"
    y, u = data()
    constant = r"^u is constant over the whole record: with a free initial state and offset"
    free = ae.Record(y, np.zeros(N), DT)
    return [
        Case(area, "n4sid on a (y, u, dt) tuple", lambda x: ae.baselines.n4sid(
            (y[DELAY:], u[:-DELAY], DT), order=2),
             raises=None, check=lambda e: bool(np.allclose(
                 np.sort_complex(np.linalg.eigvals(e.A)), np.sort_complex(TRUE_POLES),
                 rtol=1e-3))),
        Case(area, "least squares on a tuple", lambda x: ae.baselines.least_squares(
            (y[DELAY:], u[:-DELAY], DT), order=2),
             raises=None, check=lambda e: bool(np.allclose(
                 np.sort_complex(np.linalg.eigvals(e.A)), np.sort_complex(TRUE_POLES),
                 rtol=1e-6))),
        Case(area, "n4sid free response (u zero)", lambda x: ae.baselines.n4sid(free, order=2),
             match=constant),
        Case(area, "least squares constant input", lambda x: ae.baselines.least_squares(
            ae.Record(y, np.ones(N), DT), order=2), match=constant),
        Case(area, "n4sid constant output", lambda x: ae.baselines.n4sid(
            ae.Record(np.zeros(N), u, DT), order=2),
             match=r"^y is constant \(every sample is 0\)"),
        Case(area, "n4sid, tiny output 1e-200", lambda x: ae.baselines.n4sid(
            ae.Record(y[DELAY:] * 1e-200, u[:-DELAY], DT), order=2),
             raises=None, check=lambda e: dc_exact(e, 1e-200, 1e-8)),
        Case(area, "least squares, huge output 1e200", lambda x: ae.baselines.least_squares(
            ae.Record(y[DELAY:] * 1e200, u[:-DELAY], DT), order=2),
             raises=None, check=lambda e: dc_exact(e, 1e200, 1e-10)),
        Case(area, "least squares, output 1e-30", lambda x: ae.baselines.least_squares(
            ae.Record(y[DELAY:] * 1e-30, u[:-DELAY], DT), order=2),
             raises=None, check=lambda e: dc_exact(e, 1e-30, 1e-10)),
        Case(area, "n4sid, input level 1e6 +- 1", lambda x: ae.baselines.n4sid(
            ae.Record(y[DELAY:], u[:-DELAY] + 1e6, DT), order=2),
             raises=None, check=lambda e: dc_exact(e, 1.0, 1e-8)),
        Case(area, "n4sid tuple with u beside it", lambda x: ae.baselines.n4sid(
            (y, u, DT), u, order=2),
             match=r"^u must not be given with a Record"),
    ]


def _head() -> list[Case]:
    from aeid_struct.identification import Head
    area = "head"

    def bad_head(x):
        import aeid_struct as ae
        ident = ae.load_pretrained("leg-stable-any")
        ident.head = Head(iterations=3, fixed={"a0": 1e308})
        u, y = x.u300
        return ident.identify(y, u, refine=True)

    def bad_head_collect(x):
        import aeid_struct as ae
        ident = ae.load_pretrained("leg-stable-any")
        ident.head = Head(iterations=3, fixed={"a0": 1e308})
        u, y = x.u300
        return ident.identify(np.stack([y, y]), np.stack([u, u]), errors="collect")

    def bad_head_file(x):
        import aeid_struct as ae
        from aeid_struct.identification import Identifier
        ident = ae.load_pretrained("leg-stable-any")
        ident.head = Head(iterations=3, fixed={"a0": 1e308})
        path = ident.save(x.tmp / "bad-head.aeid")
        u, y = x.u300
        return Identifier.load(path).identify(y, u, refine=True)

    def bad_head_onnx(x):
        import aeid_struct as ae
        from aeid_struct.online import OnnxIdentifier, to_onnx
        ident = ae.load_pretrained("leg-stable-any")
        ident.head = Head(iterations=3, fixed={"a0": 1e308})
        u, y = x.u300
        return OnnxIdentifier(to_onnx(ident, x.tmp / "bad-head.onnx"))(y, u)

    from aeid_struct.records import RecordError
    return [
        Case(area, "a0 = 1e308 from an .aeid file", bad_head_file, raises=RecordError,
             match=r"^head: the separable head found no finite model for record 0 with the "
                   r"elements it holds fixed \(\{'a0': 1e\+308\} besides"),
        Case(area, "a0 = 1e308 through ONNX", bad_head_onnx, raises=RecordError,
             match=r"^head: the separable head found no finite model for record 0"),
        Case(area, "fixed an int beyond float64", lambda x: Head(fixed={"c1": 10 ** 400}),
             match=r"^head: fixed must be a dict element name -> finite number \(float64\); "
                   r"got 'c1': an integer of 401 digits"),
        Case(area, "fixed NaN", lambda x: Head(fixed={"c1": float("nan")}),
             match=r"^head: fixed must be a dict element name -> finite number \(float64\); "
                   r"got 'c1': nan"),
        Case(area, "fixed a list", lambda x: Head(fixed=[("c1", 0.0)]),
             match=r"^head: fixed must be a dict element name -> finite number; got list"),
        Case(area, "iterations a float", lambda x: Head(iterations=2.0),
             match=r"^head: iterations must be an integer in \[0, 50\]; got 2.0"),
        Case(area, "a0 = 1e308: no silent fall-back", bad_head, raises=RecordError,
             match=r"^head: the separable head found no finite model for record 0"),
        Case(area, "a0 = 1e308 collected", bad_head_collect, raises=None,
             check=lambda e: e.errors is not None and all(
                 r is not None and "separable head found no finite model" in str(r)
                 for r in e.errors) and bool(np.all(np.isnan(e.A)))),
    ]


def _generic_files() -> list[Case]:
    area = "generic-file"

    def with_config(x, name, **change):
        from importlib.resources import files

        from safetensors import safe_open
        from safetensors.torch import save_file

        from aeid_struct.generic import load_generic
        src = str(files("aeid_struct.pretrained") / "generic-2.aeid")
        with safe_open(src, framework="pt") as f:
            head = json.loads(f.metadata()["aeid"])
            tensors = {k: f.get_tensor(k) for k in f.keys()}
        head["config"].update(change)
        path = x.tmp / name
        save_file(tensors, str(path), metadata={"aeid": json.dumps(head)})
        return load_generic(path)

    return [
        Case(area, "width 10**9", lambda x: with_config(x, "w.aeid", width=10 ** 9),
             match=r"header entry 'config' is not valid: width must be at most 4096; got "
                   r"1000000000"),
        Case(area, "window 10**8", lambda x: with_config(x, "win.aeid", window=10 ** 8),
             match=r"header entry 'config' is not valid: window must be an integer in \[16, "
                   r"65536\] \(samples\); got 100000000"),
        Case(area, "dense huge", lambda x: with_config(x, "d.aeid", dense=[60000, 60000]),
             match=r"header entry 'config' is not valid: the encoder of this shape .* weights, "
                   r"more than 50000000"),
        Case(area, "order as a string", lambda x: with_config(x, "o.aeid", order="2"),
             match=r"header entry 'config' is not valid: order must be an integer in 1..4"),
    ]


def _cli_any() -> list[Case]:
    from aeid_struct.cli import UsageExit
    area = "cli-any"
    y, u = data()

    def run(x, *extra, yy=None, dt="0.05"):
        return cli("identify", x.npy("y21.npy", y if yy is None else yy), "--u",
                   x.npy("u21.npy", u), "--dt", dt, "--order", "2", *extra)

    return [
        Case(area, "identify --order 2 is exact", lambda x: run(x), raises=None,
             check=lambda r: r in (None, 0)),
        Case(area, "y of 1e200 identified", lambda x: run(x, yy=y * 1e200), raises=None,
             check=lambda r: r in (None, 0)),
        # several outputs come as numbered CSV columns; a (steps, 2) .npy is not one record
        Case(area, "several outputs in the .npy", lambda x: cli(
            "identify", x.npy("y2col.npy", np.stack([y, y], 1)), "--u", x.npy("u21.npy", u),
            "--dt", "0.05", "--order", "2"), raises=UsageExit,
             match=r"RECORD file .*y2col.npy' holds 600 rows of 2 values; expected one record: "
                   r"name its columns .* 't,u1,u2,y1,y2' for several inputs and outputs"),
        Case(area, "--dt 1e-300", lambda x: run(x, dt="1e-300"), raises=UsageExit,
             match=r"dt must give an order-2 model that float64 can hold"),
        Case(area, "train-generic --window 10**8", lambda x: cli(
            "train-generic", "--order", "2", "--window", "100000000", "--out",
            str(x.tmp / "g.aeid")), raises=UsageExit,
             match=r"train-generic: window must be an integer in \[16, 65536\]"),
    ]


def cases() -> list[Case]:
    """The cases of the surfaces for any system, area by area."""
    return (_record() + _identify_any() + _compare() + _baselines_record() + _head()
            + _generic_files() + _cli_any())
