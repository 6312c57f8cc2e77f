"""Tests for ``symbolic/identifiability.py``: which parameters a record determines.

Oracle, independent of the code under test: the rank of central finite differences (in
log-parameters) of the transfer-function coefficients ``scipy.signal.ss2tf`` gives for
linearisations typed by hand (paper Eq. 16 in ``symbolic.slip``, Newton's law for the others),
and the closed forms of the transfer functions (``G = r / (m s^2 + d s + k)`` for the lever).
"""

from __future__ import annotations

import casadi
import numpy as np
import pytest
import scipy.signal

from symbolic import mechanisms, slip
from symbolic.identifiability import identifiability
from symbolic.mechanism import Mechanism
from tests.test_mechanism import _cart_pole_oracle, _hanging_pendulum, _two_mass_oracle

LEG_BOX = {"k": (20.0, 25.0), "d": (2.0, 5.0), "m": (0.5, 1.5)}
TWO_MASS_BOX = {n: (0.5, 2.0) for n in ("m1", "m2", "k1", "k2", "c1", "c2")}
LEVER_BOX = {"m": (0.5, 2.0), "k": (10.0, 50.0), "d": (0.5, 3.0), "r": (0.5, 2.0)}
CART_BOX = {"M": (0.5, 2.0), "m": (0.05, 0.5), "l": (0.2, 1.0), "b": (0.05, 1.0)}


def _leg_rotation(k, d, m):
    A, B = (np.array(v) for v in slip.eq16()(k, d, m, slip.L0, slip.G))
    return A[2:, 2:], B[2:, 1:], np.array([[1.0, 0.0]]), np.zeros((1, 1))


def _lever(m, k, d, r):
    return np.array([[0, 1], [-k / m, -d / m]]), np.array([[0], [r / m]]), \
        np.array([[1.0, 0]]), np.zeros((1, 1))


def _oracle_rank(model, point: dict, rng, pairs=None) -> int:
    """Rank of d(transfer-function coefficients) / d log p by central differences: of the
    model's first input, or of each ``(output, input)`` of ``pairs``."""
    names = list(point)

    def coefficients(theta):
        A, B, C, D = model(**dict(zip(names, np.exp(theta), strict=True)))
        out = []
        for o, i in pairs or [(slice(None), 0)]:
            num, den = scipy.signal.ss2tf(A, B[:, [i]], C[o], D[o, [i]])
            out += [num.ravel() / den[0], den[1:] / den[0]]
        return np.concatenate(out)

    theta = np.log(np.array(list(point.values())))
    h = 1e-5
    J = np.column_stack([(coefficients(theta + h * e) - coefficients(theta - h * e)) / (2 * h)
                         for e in np.eye(len(names))])
    # coefficients that are zero for every p (a numerator's leading terms) are left out: ss2tf
    # returns them as round-off, which relative weights would amplify into a rank
    k = np.abs(coefficients(theta))
    keep = k > 1e-9 * k.max()
    s = np.linalg.svd(J[keep] / np.maximum(k[keep], 1e-3)[:, None], compute_uv=False)
    return int(np.sum(s > 1e-6 * s[0]))


def _draw(box, rng):
    return {k: float(rng.uniform(*v)) for k, v in box.items()}


@pytest.mark.parametrize(("mechanism", "box", "oracle", "operating"), [
    ("two_mass", TWO_MASS_BOX, _two_mass_oracle, {}),
    ("lever", LEVER_BOX, _lever, {}),
    ("cart_pole", CART_BOX, _cart_pole_oracle, {"q": [0, 0], "known": {"g": 9.81}}),
])
def test_rank_agrees_with_an_independent_rank_computation(mechanism, box, oracle, operating):
    report = identifiability(getattr(mechanisms, mechanism)(), box, **operating)
    rng = np.random.default_rng(3)
    assert report.rank == max(_oracle_rank(oracle, _draw(box, rng), rng) for _ in range(3))


def test_the_unstable_leg_record_alone_cannot_determine_d():
    legs = mechanisms.leg()
    report = identifiability(legs, LEG_BOX, inputs=[1], outputs=[1], **mechanisms.upright(legs))
    assert report.rank == 2 == _oracle_rank(_leg_rotation, slip.SCENARIO, None)
    assert report.identifiable == ("k", "m") and report.unidentifiable == ("d",)
    assert report.combinations == ({"d": 1.0},) and report.fix == ("d",)
    assert "d not identifiable" in str(report)
    assert np.isfinite(report.condition) and report.condition > 1


@pytest.mark.parametrize(("inputs", "outputs"), [([0], [0]), (None, None)])
def test_the_translational_or_both_leg_records_determine_everything(inputs, outputs):
    legs = mechanisms.leg()
    report = identifiability(legs, LEG_BOX, inputs=inputs, outputs=outputs,
                             **mechanisms.upright(legs))
    assert report.full and report.rank == 3 and report.identifiable == ("k", "d", "m")
    assert report.combinations == () and report.fix == ()


def test_a_lever_of_unknown_ratio_hides_one_scaling():
    report = identifiability(mechanisms.lever(), LEVER_BOX)
    # G = r / (m s^2 + d s + k): only r/m, k/m, d/m; scaling all four together is unseen
    assert report.rank == 3 and report.identifiable == ()
    assert report.combinations == ({"m": 1.0, "k": 1.0, "d": 1.0, "r": 1.0},)
    assert report.fix == ("r",)
    fixed = identifiability(mechanisms.lever(), {k: v for k, v in LEVER_BOX.items() if k != "r"},
                            known={"r": 1.0})
    assert fixed.full and fixed.rank == 3


def test_each_output_of_the_cart_pole_determines_all_four():
    cart = mechanisms.cart_pole()
    for outputs in (None, [0], [1]):
        report = identifiability(cart, CART_BOX, q=[0, 0], known={"g": 9.81}, outputs=outputs)
        assert report.full and report.rank == 4, outputs
        assert report.identifiable == ("M", "m", "l", "b")


def test_rank_drops_are_reported_with_their_condition_number():
    # at the centre of a box shared by all six, the two-mass parameters are all equal: a thin
    # set where the rank drops
    report = identifiability(mechanisms.two_mass(), TWO_MASS_BOX)
    assert report.full and report.rank == 6
    centre = [drop for drop in report.drops if set(drop["values"].values()) == {1.25}]
    assert len(centre) == 1 and centre[0]["rank"] < 6 and centre[0]["condition"] > 1e8
    assert np.isfinite(report.condition)


@pytest.mark.parametrize(("call", "message"), [
    ({"bounds": {"m": (1, 2)}}, "bounds must name exactly"),
    ({"bounds": {**LEVER_BOX, "m": (2.0, 1.0)}}, r"bounds\['m'\] must be finite with low < high"),
    ({"bounds": {**LEVER_BOX, "m": "heavy"}}, r"bounds\['m'\] must be a pair"),
    ({"bounds": LEVER_BOX, "inputs": [1]}, r"inputs must be distinct indices in \[0, 1\)"),
    ({"bounds": LEVER_BOX, "points": 0}, "points must be an int >= 1"),
])
def test_bad_arguments_are_refused_by_name(call, message):
    with pytest.raises(ValueError, match=message):
        identifiability(mechanisms.lever(), **call)


def _crosstalk() -> Mechanism:
    """Two masses on their own springs (common damping ``c``), a force on each, the first force
    reaching the second mass too (crosstalk ``e``); both positions out."""
    q, dq, F = casadi.SX.sym("q", 2), casadi.SX.sym("dq", 2), casadi.SX.sym("F", 2)
    p = {k: casadi.SX.sym(k) for k in ("m1", "m2", "k1", "k2", "e", "c")}
    return Mechanism(q=q, dq=dq, u=F, parameters=p,
                     lagrangian=0.5 * (p["m1"] * dq[0] ** 2 + p["m2"] * dq[1] ** 2)
                     - 0.5 * (p["k1"] * q[0] ** 2 + p["k2"] * q[1] ** 2),
                     dissipation=0.5 * p["c"] * (dq[0] ** 2 + dq[1] ** 2),
                     forces=casadi.vertcat(F[0], F[1] + p["e"] * F[0]), outputs=q,
                     name="crosstalk")


CROSSTALK_BOX = {"m1": (0.5, 2.0), "m2": (0.5, 2.0), "k1": (1.0, 5.0), "k2": (1.0, 5.0),
                 "e": (0.1, 0.5)}


def _crosstalk_model(m1, m2, k1, k2, e, c=0.5):
    """Newton's law of :func:`_crosstalk`, typed by hand."""
    A = np.array([[0, 1, 0, 0], [-k1 / m1, -c / m1, 0, 0], [0, 0, 0, 1],
                  [0, 0, -k2 / m2, -c / m2]])
    B = np.array([[0, 0], [1 / m1, 0], [0, 0], [e / m2, 1 / m2]])
    return A, B, np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]]), np.zeros((2, 2))


@pytest.mark.parametrize(("pairs", "hidden"), [
    ([(0, 0), (1, 1)], ("e",)),            # the crosstalk lives on the channel not measured
    ([(0, 0), (1, 0)], ()),
    ([(0, 0), (1, 0), (0, 1), (1, 1)], ()),
])
def test_pairs_read_only_the_channels_measured(pairs, hidden):
    """Records of separate experiments (``pairs``): a parameter seen only on a channel that
    was not measured is not identifiable, though its input and output appear in others."""
    mech = _crosstalk()
    report = identifiability(mech, CROSSTALK_BOX, known={"c": 0.5}, pairs=pairs)
    rng = np.random.default_rng(5)
    assert report.rank == max(_oracle_rank(_crosstalk_model, _draw(CROSSTALK_BOX, rng), rng,
                                           pairs) for _ in range(3))
    assert report.unidentifiable == hidden and report.pairs == tuple(pairs)
    assert ("e not identifiable" in str(report)) == bool(hidden)
    assert "y[1] from u[1]" in str(report) or (1, 1) not in pairs
    # every output of every input: the crosstalk is seen
    assert identifiability(mech, CROSSTALK_BOX, known={"c": 0.5}).full


@pytest.mark.parametrize(("call", "message"), [
    ({"pairs": [(0, 0), (0, 0)]}, r"pairs must be distinct \(output, input\)"),
    ({"pairs": [(0, 2)]}, r"pairs must be distinct .* in \[0, 2\) x \[0, 2\)"),
    ({"pairs": [(0, 0)], "inputs": [0]}, "give pairs, or inputs and outputs, not both"),
    ({"pairs": "y0u0"}, "pairs must be distinct"),
    ({"pairs": [(0, 0.5)]}, r"pairs must be distinct .* got \[\(0, 0.5\)\]"),
    ({"pairs": [(0, 0, 1)]}, "pairs must be distinct"),
])
def test_bad_pairs_are_refused_by_name(call, message):
    with pytest.raises(ValueError, match=message):
        identifiability(_crosstalk(), CROSSTALK_BOX, known={"c": 0.5}, **call)


def test_the_mechanism_answers_for_itself():
    lever = mechanisms.lever()
    assert lever.identifiability(LEVER_BOX) == identifiability(lever, LEVER_BOX)


def _quarter_car() -> Mechanism:
    """A quarter car written as a user would (not shipped): sprung mass ``ms`` on a suspension
    ``ks, cs``, unsprung mass ``mu`` on a tyre ``kt`` whose base follows the road ``u``; both
    heights measured."""
    q, dq, u = casadi.SX.sym("q", 2), casadi.SX.sym("dq", 2), casadi.SX.sym("u", 1)
    p = {k: casadi.SX.sym(k) for k in ("ms", "mu", "ks", "cs", "kt")}
    T = 0.5 * p["ms"] * dq[0] ** 2 + 0.5 * p["mu"] * dq[1] ** 2
    V = 0.5 * p["ks"] * (q[0] - q[1]) ** 2 + 0.5 * p["kt"] * (q[1] - u[0]) ** 2
    return Mechanism(q=q, dq=dq, u=u, parameters=p, lagrangian=T - V,
                     dissipation=0.5 * p["cs"] * (dq[0] - dq[1]) ** 2, outputs=q,
                     name="quarter_car")


def _quarter_car_oracle(ms, mu, ks, cs, kt):
    """Newton's law: ``ms zs'' = -ks (zs - zu) - cs (zs' - zu')``,
    ``mu zu'' = ks (zs - zu) + cs (zs' - zu') - kt (zu - u)``."""
    A = np.array([[0, 0, 1, 0], [0, 0, 0, 1], [-ks / ms, ks / ms, -cs / ms, cs / ms],
                  [ks / mu, -(ks + kt) / mu, cs / mu, -cs / mu]])
    return A, np.array([[0], [0], [0], [kt / mu]]), np.hstack([np.eye(2), np.zeros((2, 2))]), \
        np.zeros((2, 1))


QUARTER_BOX = {"ms": (200.0, 400.0), "mu": (30.0, 60.0), "ks": (1e4, 3e4),
               "cs": (800.0, 2000.0), "kt": (1.5e5, 2.5e5)}


def test_a_road_driven_quarter_car_hides_the_common_scale_of_its_parameters():
    # a displacement input: every force scales with the masses, so multiplying all five
    # parameters by one factor leaves both heights unchanged (rank 4 of 5 by the oracle too);
    # with the tyre's stiffness known the rest is determined
    car = _quarter_car()
    report = identifiability(car, QUARTER_BOX)
    rng = np.random.default_rng(5)
    assert report.rank == 4 == max(_oracle_rank(_quarter_car_oracle, _draw(QUARTER_BOX, rng), rng)
                                   for _ in range(3))
    assert report.identifiable == ()
    assert report.combinations == ({k: 1.0 for k in QUARTER_BOX},)
    assert len(report.fix) == 1 and report.fix[0] in QUARTER_BOX
    box = {k: v for k, v in QUARTER_BOX.items() if k != "kt"}
    fixed = identifiability(car, box, known={"kt": 2e5})
    assert fixed.full and fixed.identifiable == ("ms", "mu", "ks", "cs")


def test_a_hanging_pendulum_determines_mass_length_and_friction():
    # G = 1 / (m l^2 s^2 + b s + m g l): three coefficients, three parameters
    report = identifiability(_hanging_pendulum(), {"m": (0.2, 1.0), "l": (0.2, 0.8),
                                                   "b": (0.01, 0.2)}, known={"g": 9.81})
    assert report.full and report.identifiable == ("m", "l", "b")
