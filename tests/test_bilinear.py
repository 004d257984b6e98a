"""BilinearModel, exact lifts, and the generated tensor systems against seed 001 Appendices A-B."""

import re

import numpy as np
import pytest
import sympy as sp

from nlfilter.bilinear import BilinearModel, phase_model
from nlfilter.errors import MomentsNotClosedError, NotPolynomialError, SingularSystemError
from nlfilter.models import SDEModel
from nlfilter.moments.closed import bilinear_lift, closed_hull
from nlfilter.moments.ito import PolynomialSDE, moment_equations
from nlfilter.moments.solve import linear_steady_state, stationary_moments, steady_state
from nlfilter.polynomials import monomials

# ---------------------------------------------------------------------------------------------
# seed 001, Appendices A and B, every "nonzero element" as OCR'd (verbatim, one entry "row,col=value")
APPENDIX = r"""
A A: 1,1=-q/2; 9,35=K^2 r; 2,2=-q/2; 10,10=-q - 2K; 3,1=K; 10,12=K; 3,3=-\frac{q}{2} - K; 10,13=K;
    4,2=K; 11,5=K; 4,4=-\frac{q}{2} - K; 11,11=-q - 2K; 5,5=-q; 12,7=K; 5,6=q; 12,12=-q - 2K;
    6,5=q; 13,7=K; 6,6=-q; 13,13=-q - 2K; 7,7=-2q; 14,6=K; 8,8=-q - 2K; 14,14=-q - 2K; 8,11=2K;
    15,15=-\frac{3}{2}q; 8,35=K^2 r; 15,19=3q; 9,9=-q - 2K; 16,16=-\frac{7}{2}q; 9,14=2K; 16,25=q;
    17,15=K; 23,23=-\frac{5}{2}q - K; 17,17=-\frac{3}{2}q - K; 24,18=K; 17,26=q; 24,22=K; 18,16=K;
    24,24=-\frac{3}{2}q - 2K; 18,18=-\frac{3}{2}q - K; 25,16=3q; 18,27=q; 25,25=-\frac{3}{2}q;
    19,15=q; 26,17=q; 19,19=-\frac{7}{2}q; 26,19=K; 20,1=K^2r; 26,26=-\frac{3}{2}q - K; 20,17=2K;
    27,18=q; 20,20=-\frac{3}{2}q - 2K; 27,25=K; 21,1=K^2r; 27,27=-\frac{3}{2}q - K;
    21,21=-\frac{3}{2}q - 2K; 28,2=K^2r; 21,23=2K; 28,22=2K; 22,16=K; 28,28=-\frac{3}{2}q - 2K;
    22,22=-\frac{5}{2}q - K; 29,2=K^2r; 23,19=K; 29,27=2K; 29,29=-\frac{3}{2}q - 2K; 32,28=K;
    30,23=K; 32,32=-\frac{3}{2}q - 3K; 30,26=K; 33,3=K^2r; 30,30=-\frac{3}{2}q - 2K; 33,21=K;
    31,3=3K^2r; 33,30=2K; 31,20=3K; 33,33=-\frac{3}{2}q - 3K; 31,31=-\frac{3}{2}q - 3K; 34,4=3K^2r;
    32,4=K^2r; 34,29=3K; 32,24=2K; 34,34=-\frac{3}{2}q - 3K
A B_1: 1,2=1; 12,14=1; 2,1=1; 13,11=-1; 5,7=2; 14,12=-1; 6,7=-2; 15,16=3; 7,5=-1; 16,15=-1; 7,6=1;
    16,19=2; 11,13=1; 17,22=2; 18,23=2; 19,16=-2; 19,25=1; 20,28=1; 21,29=1; 22,17=-1; 22,26=1;
    23,18=-1; 23,27=1; 24,30=1; 25,19=-3; 26,22=-2; 27,23=-2; 28,20=-1; 29,21=-1; 30,24=-1
A B_2: 3,35=K; 8,3=2K; 10,4=K; 11,1=K; 13,2=K; 17,5=K; 20,11=2K; 22,7=K; 24,12=K; 26,6=K; 28,13=2K;
    30,14=K; 31,8=3K; 32,10=2K; 33,9=K
A B_3: 4,35=K; 24,11=K; 9,4=2K; 27,6=K; 10,3=K; 29,14=2K; 12,1=K; 30,13=K; 14,2=K; 32,8=K; 18,5=K;
    33,10=2K; 21,12=2K; 34,9=3K; 23,7=K
B A: 1,1=-1; 9,9=-9; 2,2=-2; 10,4=K_1; 2,40=q; 10,10=-2; 3,1=3q; 10,16=-K_1; 3,3=-3; 11,5=K_1;
    4,2=6q; 11,11=-3; 4,4=-4; 11,17=-K_1; 5,3=10q; 11,31=q; 5,5=-5; 12,6=K_1; 6,4=15q; 12,10=3q;
    6,6=-6; 12,12=-4; 7,5=21q; 12,18=-K_1; 7,7=-7; 13,7=K_1; 8,6=28q; 13,11=6q; 8,8=-8; 13,13=-5;
    9,7=36q; 13,19=-K_1; 14,8=K_1; 14,12=10q; 14,14=-6; 14,20=-K_1; 15,9=K_1; 15,13=15q; 15,15=-7;
    15,21=-K_1; 16,4=K_2; 16,10=3q; 16,16=-4 - K_2; 17,5=K_2; 17,11=3q; 17,17=-5 - K_2; 17,32=q;
    18,6=K_2; 18,12=3q; 18,16=3q; 18,18=-6 - K_2; 19,7=K_2; 19,13=3q; 19,17=6q; 19,19=-7 - K_2;
    20,8=K_2; 20,14=3q; 20,18=10q; 20,20=-8 - K_2; 21,9=K_2; 21,15=3q; 21,19=15q; 21,21=-9 - K_2;
    22,1=K_1^2 r; 22,13=2K_1; 22,22=-3; 22,28=-2K_1; 23,2=K_1^2 r; 23,14=2K_1; 23,23=-4;
    23,29=-2K_1; 23,33=q; 24,3=K_1^2 r; 24,15=2K_1; 24,22=3q; 24,24=-5; 24,30=-2K_1; 25,1=K_1^2 r;
    25,19=2K_2; 25,25=-7 - 2K_2; 25,28=6q; 26,2=K_2^2 r; 26,20=2K_2; 26,26=-8 - 2K_2; 26,29=6q;
    26,35=q; 27,3=K_2^2 r; 27,21=2K_2; 27,25=3q; 27,27=-9 - 2K_2; 27,30=6q; 28,1=K_1 K_2 r;
    28,13=K_2; 28,19=K_1; 28,22=3q; 28,25=-K_1; 28,28=-5 - K_2; 29,2=K_1 K_2 r; 29,14=K_2;
    29,20=K_1; 29,23=3q; 33,12=2K_1; 29,26=-K_1; 33,33=-2; 29,29=-6 - K_2; 33,34=-2K_1; 29,34=q;
    33,40=K_1^2 r; 30,3=K_1 K_2 r; 34,12=K_2; 30,15=K_2; 34,18=K_1; 30,21=K_1; 34,33=3q; 30,24=3q;
    34,34=-4 - K_2; 30,27=-K_1; 34,35=-K_1; 30,28=3q; 34,40=K_1 K_2 r; 30,30=-7 - K_2; 35,18=2K_2;
    31,3=K_1; 35,34=6q; 31,31=-1; 35,35=-6 - 2K_2; 31,32=-K_1; 35,40=K_2^2 r; 32,3=K_2; 36,24=3K_1;
    32,31=3q; 36,31=3K_1^2 r; 32,32=-3 - K_2; 36,36=-3; 36,37=-3K_1; 38,31=K_1^2 r; 37,24=K_2;
    38,32=2K_1 K_2 r; 37,30=2K_1; 38,37=6q; 37,31=2K_1 K_2 r; 38,38=-7 - 2K_2; 37,32=K_1^2 r;
    38,39=-K_1; 37,36=3q; 39,27=3K_2; 37,37=-5 - K_2; 39,32=3K_2^2 r; 37,38=-2K_1; 39,38=9q;
    38,27=K_1; 39,39=-9 - 3K_2; 38,30=2K_2
B B_1: 1,40=1; 7,6=7; 2,1=2; 8,7=8; 3,2=3; 9,8=9; 4,3=4; 10,31=1; 5,4=5; 11,10=2; 6,5=6; 12,11=3;
    13,12=4; 14,13=5; 15,14=6; 16,32=1; 17,16=2; 18,17=3; 19,18=4; 20,19=5; 21,20=6; 22,33=1;
    23,22=2; 24,23=3; 25,35=1; 26,25=2; 27,26=3; 28,34=1; 29,28=2; 30,29=3
B B_2: 21,6=K_2; 22,10=2K_1; 23,11=2K_1; 24,12=2K_1; 25,16=2K_2; 26,17=2K_2; 27,18=2K_2; 28,10=K_2;
    28,16=K_1; 29,11=K_2; 29,17=K_1; 30,12=K_2; 30,18=K_1; 31,40=K_1; 32,40=K_2; 37,33=K_2;
    33,31=2K_1; 37,34=2K_1; 34,31=K_2; 38,34=2K_2; 34,32=K_1; 38,35=K_1; 35,32=2K_2; 39,35=3K_2;
    36,33=3K_1
"""

q, r, K, K1, K2 = sp.symbols("q r K K1 K2", positive=True)


def _parse_value(s):
    s = (s.replace(r"\frac{3}{2}q", "3/2*q").replace(r"\frac{5}{2}q", "5/2*q").replace(r"\frac{7}{2}q", "7/2*q")
         .replace(r"\frac{q}{2}", "q/2").replace("K_1", "K1").replace("K_2", "K2"))
    s = re.sub(r"(\d)([A-Za-z])", r"\1*\2", s).replace("^", "**")
    for _ in range(2):
        s = re.sub(r"(K\d?(?:\*\*\d)?)\s*([rK])", r"\1*\2", s)
    return sp.sympify(s, locals={"q": q, "r": r, "K": K, "K1": K1, "K2": K2})


def _appendix():
    out, key = {}, None
    for line in APPENDIX.strip().splitlines():
        m = re.match(r"^([AB]) (A|B_\d): (.*)$", line)
        if m:
            key = (m.group(1), m.group(2))
            body = m.group(3)
        else:
            body = line
        for part in body.split(";"):
            part = part.strip()
            if part:
                rc, val = part.split("=", 1)
                i, j = (int(v) for v in rc.split(","))
                out.setdefault(key, {})[(i, j)] = _parse_value(val)
    return out


def _sde_A(intensity_n):
    """Joint (x1, x2, x̂1, x̂2) of 001 eqs. 4.12, 4.21-4.22, noises dθ (q), dn1, dn2 (intensity_n)."""
    x1, x2, u1, u2 = sp.symbols("x1 x2 u1 u2")
    f = [-q / 2 * x1, -q / 2 * x2, (-q / 2 - K) * u1 + K * x1, (-q / 2 - K) * u2 + K * x2]
    G = [[x2, 0, 0], [-x1, 0, 0], [0, K, 0], [0, 0, K]]
    return PolynomialSDE.from_sympy([x1, x2, u1, u2], f, G=G, Q=sp.diag(q, intensity_n, intensity_n), exact=True)


ORDER_A = [(1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 1, 0), (0, 0, 0, 1), (2, 0, 0, 0), (0, 2, 0, 0), (1, 1, 0, 0),
           (0, 0, 2, 0), (0, 0, 0, 2), (0, 0, 1, 1), (1, 0, 1, 0), (1, 0, 0, 1), (0, 1, 1, 0), (0, 1, 0, 1),
           (3, 0, 0, 0), (2, 1, 0, 0), (2, 0, 1, 0), (2, 0, 0, 1), (1, 2, 0, 0), (1, 0, 2, 0), (1, 0, 0, 2),
           (1, 1, 1, 0), (1, 1, 0, 1), (1, 0, 1, 1), (0, 3, 0, 0), (0, 2, 1, 0), (0, 2, 0, 1), (0, 1, 2, 0),
           (0, 1, 0, 2), (0, 1, 1, 1), (0, 0, 3, 0), (0, 0, 2, 1), (0, 0, 1, 2), (0, 0, 0, 3), (0, 0, 0, 0)]
# Appendix B's 40 elements: monomials x^a x̂^b (x̂³)^c, in the thesis' order (B.1 list)
ORDER_B = ([(k, 0, 0) for k in range(1, 10)] + [(k, 1, 0) for k in range(1, 7)] + [(k, 0, 1) for k in range(1, 7)]
           + [(k, 2, 0) for k in range(1, 4)] + [(k, 0, 2) for k in range(1, 4)] + [(k, 1, 1) for k in range(1, 4)]
           + [(0, 1, 0), (0, 0, 1), (0, 2, 0), (0, 1, 1), (0, 0, 2), (0, 3, 0), (0, 2, 1), (0, 1, 2), (0, 0, 3), (0, 0, 0)])


def _sde_B():
    """Joint (x, x̂, x̂³) of the cubic sensor's linear filter (001 eqs. 5.1-5.6, B.5-B.6)."""
    x, u, v = sp.symbols("x u v")
    f = [-x, -u + K1 * (x ** 3 - v), 3 * q * u - 3 * v + K2 * (x ** 3 - v)]
    return PolynomialSDE.from_sympy([x, u, v], f, G=[[1, 0], [0, K1], [0, K2]], Q=sp.diag(q, r), exact=True)


def _diff(gen, app):
    N = gen.shape[0]
    out = {}
    for i in range(N):
        for j in range(N):
            g, a = sp.expand(gen[i, j]), sp.expand(app.get((i + 1, j + 1), 0))
            if sp.simplify(g - a) != 0:
                out[(i + 1, j + 1)] = (g, a)
    return out


def _ito_entry(sde_vars, f, G, Q, order, i, j, noise=None):
    """Independent check of one entry by SymPy differentiation of the monomial (001 eq. 2.16)."""
    xs = sde_vars
    mon = sp.Mul(*[v ** a for v, a in zip(xs, order[i])])
    grad = [sp.diff(mon, v) for v in xs]
    if noise is None:
        D = sp.Matrix(G) * sp.Matrix(Q) * sp.Matrix(G).T
        expr = sum(f[k] * grad[k] for k in range(len(xs))) + sp.Rational(1, 2) * sum(
            D[k, l] * sp.diff(mon, xs[k], xs[l]) for k in range(len(xs)) for l in range(len(xs)))
    else:
        expr = sum(sp.Matrix(G)[k, noise] * grad[k] for k in range(len(xs)))
    P = sp.Poly(sp.expand(expr), *xs)
    return P.coeff_monomial(sp.Mul(*[v ** a for v, a in zip(xs, order[j])]))


def test_appendix_A_generated_entry_by_entry():
    """Appendix A (phase tracking, x_[3] of (x1, x2, x̂1, x̂2, 1)): 35x35 A and B1..B3, generated.

    Disagreements, each with its reason (checked below by an independent SymPy Itô derivation):
    * 10 entries K²r / 3K²r (rows 8, 9, 20, 21, 28, 29, 31-34): the appendix used E dn² = r dt for
      the baseband noises, but eq. 4.14 (and the gain 4.18 derived from it) has 2r: generated 2K²r /
      6K²r. With intensity r every one of them agrees (asserted).
    * A(11,11) .. A(14,14) = −q − 2K in the appendix: d(x_i x̂_j) = x̂_j dx_i + x_i dx̂_j has
      −q/2 from x_i and −q/2 − K from x̂_j: −q − K (A(8,8) = −q − 2K is right, for x̂²).
    * B1(2,1) = 1 in the OCR: eq. 4.12 gives dx2 = −x1 dθ, so −1 (a lost minus sign).
    """
    sde = _sde_A(2 * r)
    A, Bs = bilinear_lift(sde, ORDER_A)
    app = _appendix()
    diffs = {name: _diff(gen, app[("A", name)]) for name, gen in zip(("A", "B_1", "B_2", "B_3"), [A, *Bs])}
    factor2 = {(8, 35), (9, 35), (20, 1), (21, 1), (28, 2), (29, 2), (31, 3), (32, 4), (33, 3), (34, 4)}
    diag = {(11, 11), (12, 12), (13, 13), (14, 14)}
    assert set(diffs["A"]) == factor2 | diag
    assert set(diffs["B_1"]) == {(2, 1)} and not diffs["B_2"] and not diffs["B_3"]
    for (i, j) in factor2:
        g, a = diffs["A"][(i, j)]
        assert sp.simplify(g - 2 * a) == 0
    # with the appendix's intensity r the factor-2 entries agree
    A_r, _ = bilinear_lift(_sde_A(r), ORDER_A)
    assert set(_diff(A_r, app[("A", "A")])) == diag
    # independent derivation of every disagreeing entry
    x1, x2, u1, u2 = sp.symbols("x1 x2 u1 u2")
    f = [-q / 2 * x1, -q / 2 * x2, (-q / 2 - K) * u1 + K * x1, (-q / 2 - K) * u2 + K * x2]
    G = [[x2, 0, 0], [-x1, 0, 0], [0, K, 0], [0, 0, K]]
    Q = sp.diag(q, 2 * r, 2 * r)
    for (i, j), (g, _) in diffs["A"].items():
        assert sp.simplify(_ito_entry([x1, x2, u1, u2], f, G, Q, ORDER_A, i - 1, j - 1) - g) == 0
    assert _ito_entry([x1, x2, u1, u2], f, G, Q, ORDER_A, 1, 0, noise=0) == -1 == diffs["B_1"][(2, 1)][0]


def test_appendix_B_generated_entry_by_entry():
    """Appendix B (cubic sensor, 40 monomials of (x, x̂, x̂³)): A, B1, B2 generated.

    Disagreements, each with its reason (independent SymPy derivation below):
    * A(25,1) and A(38,31) = K1²r in the appendix: the Itô term of (x̂³)² is K2² r dt, so
      d(x (x̂³)²) and d(x̂ (x̂³)²) carry K2² r x and K2² r x̂.
    * B2(10,1) .. B2(20,5): absent from the appendix (its B2 list starts at row 21), but
      d(x^k x̂) = ... + K1 x^k dv and d(x^k x̂³) = ... + K2 x^k dv for k = 1..5 (a lost page or
      an omission: B2(21,6) = K2, the same pattern for k = 6, is printed).
    """
    sde = _sde_B()
    A, Bs = bilinear_lift(sde, ORDER_B)
    app = _appendix()
    dA = _diff(A, app[("B", "A")])
    dB1 = _diff(Bs[0], app[("B", "B_1")])
    dB2 = _diff(Bs[1], app[("B", "B_2")])
    assert set(dA) == {(25, 1), (38, 31)} and not dB1
    missing = {(10 + k, 1 + k) for k in range(6)} | {(16 + k, 1 + k) for k in range(5)}
    assert set(dB2) == missing and all(a == 0 for _, a in dB2.values())
    x, u, v = sp.symbols("x u v")
    f = [-x, -u + K1 * (x ** 3 - v), 3 * q * u - 3 * v + K2 * (x ** 3 - v)]
    G = [[1, 0], [0, K1], [0, K2]]
    for (i, j), (g, a) in dA.items():
        assert sp.simplify(_ito_entry([x, u, v], f, G, sp.diag(q, r), ORDER_B, i - 1, j - 1) - g) == 0
        assert sp.simplify(g - K2 ** 2 * r) == 0 and sp.simplify(a - K1 ** 2 * r) == 0
    for (i, j), (g, _) in dB2.items():
        assert sp.simplify(_ito_entry([x, u, v], f, G, sp.diag(q, r), ORDER_B, i - 1, j - 1, noise=1) - g) == 0


def test_appendix_B_set_is_the_closed_set():
    """The 39 non-constant monomials of Appendix B are exactly the weighted-degree ≤ 9 set
    (weights 1, 3, 3), closed under the Itô generator and the noise coefficients."""
    sde = _sde_B()
    closed = closed_hull(sde, [(9, 0, 0), (6, 1, 0), (6, 0, 1), (0, 0, 3), (3, 2, 0), (0, 3, 0)], with_noise=True)
    assert set(closed) == set(ORDER_B) - {(0, 0, 0)}
    assert set(monomials(3, 9, min_degree=1, weights=[1, 3, 3])) == set(closed)


# ---------------------------------------------------------------------------------------------
def test_augmentation_of_additive_noise():
    """001 §2.2: dx = x dt + x dη + dw becomes dz = F z dt + G1 z dη + G2 z dw, z = (x, 1)."""
    m = BilinearModel([[1.0]], [[1.0]], G=[[[1.0]]], B=[[1.0]], R=[[1.0]])
    a = m.augmented(0)
    assert np.allclose(a.F, [[1, 0], [0, 0]])
    assert np.allclose(a.G[0], [[1, 0], [0, 0]]) and np.allclose(a.G[1], [[0, 1], [0, 0]])
    assert np.allclose(a.M[0], [[0, 1]])  # dv = M z dv with the constant state


def test_cubic_sensor_lift_matches_eq_5_5():
    """001 eq. 5.5 (q = 1.7): F, G and H of (x, x², x³, 1), noises standardised by √q."""
    qv = 1.7
    x = sp.Symbol("x")
    lift = BilinearModel.from_polynomial(SDEModel([x], [-x], [x ** 3], Q=qv, R=0.3))
    a = lift.augmented(0)
    F = np.array([[-1, 0, 0, 0], [0, -2, 0, qv], [3 * qv, 0, -3, 0], [0, 0, 0, 0]])
    G = np.sqrt(qv) * np.array([[0, 0, 0, 1], [2, 0, 0, 0], [0, 3, 0, 0], [0, 0, 0, 0]])
    assert np.allclose(a.F, F) and np.allclose(a.G[0], G) and np.allclose(a.H, [[0, 0, 1, 0]])
    assert np.allclose(a.M[0], [[0, 0, 0, np.sqrt(0.3)]])


def test_lift_rejects_nonlinear_drift():
    x = sp.Symbol("x")
    with pytest.raises(NotPolynomialError, match="degree 3"):
        BilinearModel.from_polynomial(SDEModel([x], [-x ** 3], [x], Q=1.0, R=1.0))
    with pytest.raises(NotPolynomialError):
        BilinearModel.from_polynomial(SDEModel([x], [-x], [sp.sin(x)], Q=1.0, R=1.0))


def test_to_sde_round_trip_drift_and_noise():
    m = phase_model(0.7, 0.2)
    sde = m.to_sde()
    z = np.array([[0.6, 0.8], [1.0, 0.0]])
    assert np.allclose(sde.f(z), -0.35 * z)
    assert np.allclose(sde.GQGT(z), 0.7 * np.einsum("bi,bj->bij", z[:, ::-1] * [1, -1], z[:, ::-1] * [1, -1]))
    assert np.allclose(sde.R, 0.4 * np.eye(2))


def test_bad_inputs_name_the_argument():
    with pytest.raises(ValueError, match="H"):
        BilinearModel(np.eye(2), np.ones((1, 3)), R=[[1.0]])
    with pytest.raises(ValueError, match="M, R"):
        BilinearModel(np.eye(1), np.eye(1))
    with pytest.raises(ValueError, match="q"):
        phase_model(-1.0, 1.0)


def test_moments_of_geometric_brownian_motion_exact():
    """001 eq. 3.9: dx = a x dt + b x dw, d/dt E x^p = (a + b²(p−1)/2) p E x^p (closed form)."""
    x = sp.Symbol("x")
    a, b = -1.3, 0.6
    sde = PolynomialSDE.from_sympy([x], [a * x], G=[[b * x]], Q=1.0)
    eq = moment_equations(sde, closed_hull(sde, [(4,)]))
    assert eq.indices == [(4,)]
    assert eq.A.toarray()[0, 0] == pytest.approx((a + b * b * 1.5) * 4)


def test_steady_state_circle_requires_and_uses_conservation_laws():
    """On the circle the moment matrix is singular; without initial moments the solver refuses,
    with them it returns the uniform law's moments (E x1² = 1/2, E x1⁴ = 3/8, E x1²x2² = 1/8)."""
    x1, x2 = sp.symbols("x1 x2")
    sde = PolynomialSDE.from_sympy([x1, x2], [-x1 / 2, -x2 / 2], G=[[x2], [-x1]], Q=1.0)
    eq = moment_equations(sde, closed_hull(sde, [(4, 0), (2, 2), (2, 0)]))
    with pytest.raises(SingularSystemError, match="conserve"):
        linear_steady_state(eq.A, eq.c, indices=eq.indices)
    from nlfilter.filters.phase import circle_moment
    mu = dict(zip(eq.indices, linear_steady_state(eq.A, eq.c, indices=eq.indices, initial=circle_moment)))
    assert mu[(2, 0)] == pytest.approx(0.5) and mu[(4, 0)] == pytest.approx(3 / 8) and mu[(2, 2)] == pytest.approx(1 / 8)
    # the engine's steady_state names the conserved combinations, and takes the same route given initial moments
    with pytest.raises(SingularSystemError, match=r"conserve 2 combination\(s\)"):
        steady_state(eq)
    assert np.array_equal(steady_state(eq, initial=circle_moment), np.array(list(mu.values())))
    # a least-squares solve of the singular system alone is finite but wrong: the trap the check avoids
    lsq = np.linalg.lstsq(eq.A.toarray(), -eq.c, rcond=None)[0]
    assert abs(dict(zip(eq.indices, lsq))[(2, 0)] - 0.5) > 0.1


def test_steady_state_unstable_moments_raise():
    x = sp.Symbol("x")
    sde = PolynomialSDE.from_sympy([x], [-x], G=[[1.5 * x]], Q=1.0)  # 2a + b² = 0.25 > 0: E x² grows
    with pytest.raises(SingularSystemError, match="without bound"):
        stationary_moments(sde, [(2,)])


def test_closed_hull_detects_nonclosing_hierarchy():
    x = sp.Symbol("x")
    sde = PolynomialSDE.from_sympy([x], [-x ** 3], G=[[1]], Q=1.0)
    with pytest.raises(MomentsNotClosedError):
        closed_hull(sde, [(2,)], max_size=50, with_noise=True)
