"""The efficient RK pairs' tables checked by the order conditions (Butcher's rooted trees):
for every rooted tree t of order |t| <= p, b . Phi(t) = 1/gamma(t), with Phi(leaf) = 1 and
Phi([t1..tm]) = prod_i A Phi(t_i) (Hairer, Norsett & Wanner I, sec. II.2). Verner's tables
are rationals: the conditions hold exactly; Tsitouras' are 16-digit decimals."""
from __future__ import annotations

import functools
from fractions import Fraction

import numpy as np
import pytest

from cvj_ros.physics.erk_tableaux import ERK_METHODS, erk_exact, erk_tableau


@functools.lru_cache(maxsize=None)
def trees(order: int) -> tuple:
    """Rooted trees with ``order`` nodes, each a sorted tuple of its children's trees."""
    if order == 1:
        return ((),)
    out = set()
    # children: a multiset of trees whose orders sum to order - 1
    def forests(total: int, max_key):
        if total == 0:
            yield ()
            return
        for k in range(1, total + 1):
            for t in trees(k):
                key = (k, t)
                if max_key is not None and key > max_key:
                    continue
                for rest in forests(total - k, key):
                    yield (t,) + rest
    for f in forests(order - 1, None):
        out.add(tuple(sorted(f, key=lambda t: (_size(t), t))))
    return tuple(sorted(out, key=repr))


def _size(t) -> int:
    return 1 + sum(_size(c) for c in t)


def _gamma(t) -> int:
    g = _size(t)
    for c in t:
        g *= _gamma(c)
    return g


def _matrix(ex: dict, zero):
    s_all = len(ex['c'])
    A = [[zero] * s_all for _ in range(s_all)]
    for i, row in enumerate(ex['a']):
        for j, v in enumerate(row):
            A[i][j] = v
    return A


def _phi(t, A, one):
    s = len(A)
    v = [one] * s
    for c in t:
        w = _phi(c, A, one)
        aw = [sum((A[i][j] * w[j] for j in range(s)), one * 0) for i in range(s)]
        v = [v[i] * aw[i] for i in range(s)]
    return v


def _residuals(weights, A, order: int, one, theta=None) -> list:
    """b . Phi(t) - theta^|t| / gamma(t) for every tree up to ``order``."""
    out = []
    for q in range(1, order + 1):
        for t in trees(q):
            phi = _phi(t, A, one)
            lhs = sum((weights[i] * phi[i] for i in range(len(weights))), one * 0)
            rhs = (one if theta is None else theta ** q) / _gamma(t)
            out.append(lhs - rhs)
    return out


def test_tree_counts():
    """1, 1, 2, 4, 9, 20, 48 rooted trees of orders 1..7 (OEIS A000081)."""
    assert [len(trees(q)) for q in range(1, 8)] == [1, 1, 2, 4, 9, 20, 48]


def test_vern6_exact_orders():
    """Verner 6(5): the propagated weights satisfy every condition of order <= 6 exactly, not
    all of order 7; the embedded weights (B + E) those of order <= 5, not all of order 6; the
    row sums of A are the nodes C (every stage)."""
    ex = erk_exact('vern6')
    one = Fraction(1)
    A = _matrix(ex, Fraction(0))
    for i, ci in enumerate(ex['c']):
        assert sum(A[i], Fraction(0)) == ci
    b = ex['b'] + [Fraction(0)] * (len(A) - len(ex['b']))
    assert all(r == 0 for r in _residuals(b, A, 6, one))
    assert any(r != 0 for r in _residuals(b, A, 7, one)[-48:])
    bh = [bi + ei for bi, ei in zip(ex['b'], ex['e'])] + [Fraction(0)] * 3
    assert all(r == 0 for r in _residuals(bh, A, 5, one))
    assert any(r != 0 for r in _residuals(bh, A, 6, one)[-20:])
    # FSAL: the last step stage is evaluated at the propagated solution
    S = ex['S']
    assert ex['c'][S - 1] == 1 and list(ex['a'][S - 1]) == list(ex['b'][:S - 1])


@pytest.mark.parametrize('theta', [Fraction(1, 7), Fraction(1, 2), Fraction(4, 5), Fraction(1)])
def test_vern6_interpolant_order_6(theta):
    """The continuous extension b(theta) satisfies the conditions of order <= 6 at theta
    (y(t_old + theta h) to local order 7), exactly, with the three extra stages."""
    ex = erk_exact('vern6')
    one = Fraction(1)
    A = _matrix(ex, Fraction(0))
    bt = [sum((row[d] * theta ** (d + 1) for d in range(len(row))), Fraction(0))
          for row in ex['p']]
    assert all(r == 0 for r in _residuals(bt, A, 6, one, theta))


def test_tsit5_orders():
    """Tsitouras 5(4): order 5 (not 6), embedded order 4 (not 5), to the 16 printed digits;
    its free interpolant of order 4 at several theta, and equal to B at theta = 1."""
    ex = erk_exact('tsit5')
    A = _matrix(ex, 0.0)
    for i, ci in enumerate(ex['c']):
        assert sum(A[i]) == pytest.approx(ci, abs=1e-15)
    # bound: coefficients up to ~13 printed to 16 digits leave residuals of ~1e-14
    res = _residuals(ex['b'], A, 6, 1.0)
    assert max(abs(r) for r in res[:-20]) < 1e-13
    assert max(abs(r) for r in res[-20:]) > 1e-6
    bh = [bi + ei for bi, ei in zip(ex['b'], ex['e'])]
    res = _residuals(bh, A, 5, 1.0)
    assert max(abs(r) for r in res[:-9]) < 1e-13
    assert max(abs(r) for r in res[-9:]) > 1e-6
    for theta in (0.2, 0.5, 0.9, 1.0):
        bt = [sum(row[d] * theta ** (d + 1) for d in range(4)) for row in ex['p']]
        assert max(abs(r) for r in _residuals(bt, A, 4, 1.0, theta)) < 1e-13
    b1 = [sum(row) for row in ex['p']]
    assert b1 == pytest.approx(ex['b'], abs=1e-14)


@pytest.mark.parametrize('method', ERK_METHODS)
def test_float_arrays(method):
    """erk_tableau: the floats of the published values, in the steppers' layout."""
    tab = erk_tableau(method)
    S = tab['S']
    assert tab['B'].shape == tab['E'].shape == (S,)
    assert tab['A'].shape == (tab['C'].size,) * 2 == (tab['P'].shape[0],) * 2
    assert np.array_equal(tab['A'][S - 1, :S], tab['B']) and tab['C'][S - 1] == 1.0
    assert abs(tab['E'].sum()) < 1e-13
    # vern8's interpolant weights reach 1.4e6 (row sums of |P| 4.2e6): the doubles' sum at
    # theta = 1 meets B to 2.1e-10 (measured), eps times those sums
    atol = 1e-9 if method == 'vern8' else 1e-13
    assert np.allclose(tab['P'].sum(axis=1)[:S], tab['B'], atol=atol)
    # the doubles themselves: rows sum to C and b . A 1 = 1/2 to 1e-12 (vern6's published
    # values rounded one by one missed it by 7e-12: the first column is re-rounded)
    A = [[Fraction(v) for v in row] for row in tab['A']]
    for i in range(S):
        assert abs(float(sum(A[i], Fraction(0)) - Fraction(tab['C'][i]))) < 1e-14
    b_a1 = sum((Fraction(tab['B'][i]) * sum(A[i], Fraction(0)) for i in range(S)), Fraction(0))
    assert abs(float(b_a1 - Fraction(1, 2))) < 1e-12


def test_vern7_orders():
    """Verner's efficient 7(6), his 40-digit decimals read as exact rationals: the
    propagated weights meet every condition of order <= 7 (to ~1e-38, the decimals'
    rounding; bound 1e-30), not all of order 8; the embedded weights (B + E) those of order
    <= 6, not all of order 7; rows of A sum to C; the stage after the step is
    f(t + h, y_new) (c = 1, row = b) with zero weights (laid out as FSAL)."""
    ex = erk_exact('vern7')
    one = Fraction(1)
    A = _matrix(ex, Fraction(0))
    for i, ci in enumerate(ex['c']):
        assert abs(sum(A[i], Fraction(0)) - ci) < Fraction(1, 10 ** 36)
    pad = [Fraction(0)] * (len(A) - len(ex['b']))
    b = ex['b'] + pad
    res = _residuals(b, A, 8, one)
    assert max(abs(r) for r in res[:-115]) < Fraction(1, 10 ** 30)
    assert max(abs(r) for r in res[-115:]) > Fraction(1, 10 ** 6)
    bh = [bi + ei for bi, ei in zip(ex['b'], ex['e'])] + pad
    res = _residuals(bh, A, 7, one)
    assert max(abs(r) for r in res[:-48]) < Fraction(1, 10 ** 30)
    assert max(abs(r) for r in res[-48:]) > Fraction(1, 10 ** 6)
    S = ex['S']
    assert ex['c'][S - 1] == 1 and list(ex['a'][S - 1]) == list(ex['b'][:S - 1])
    assert ex['b'][S - 1] == 0 and ex['e'][S - 1] == 0


@pytest.mark.parametrize('theta', [Fraction(1, 7), Fraction(1, 2), Fraction(4, 5), Fraction(1)])
def test_vern7_interpolant_order_7(theta):
    """Verner's continuous extension of the 7(6) pair (six extra stages, the first one
    f(t + h, y_new)) at theta: every condition of order <= 6 to the decimals' rounding (bound
    1e-30), the 48 of order 7 to 2e-7 at most (as published: 13 of them are off by 1e-9 to
    2e-7, against 1/gamma >= 2e-4; bound 1e-6), so its h^7 local error term is ~1e-7 of a
    generic one's: order 7 in practice (test_steppers_rk_nb measures the dense order)."""
    ex = erk_exact('vern7')
    A = _matrix(ex, Fraction(0))
    bt = [sum((row[d] * theta ** (d + 1) for d in range(len(row))), Fraction(0))
          for row in ex['p']]
    res = _residuals(bt, A, 7, Fraction(1), theta)
    assert max(abs(r) for r in res[:-48]) < Fraction(1, 10 ** 30)
    assert max(abs(r) for r in res[-48:]) < Fraction(1, 10 ** 6)


def test_vern8_orders():
    """Verner's efficient 8(7), his rationals: every condition of order <= 8 exactly for the
    propagated weights, not all of the first 20 of order 9; the embedded ones (B + E) every
    condition of order <= 7 exactly, not all of order 8; rows of A sum to C; stage 14 is
    f(t + h, y_new) with zero weights (laid out as FSAL)."""
    ex = erk_exact('vern8')
    S = ex['S']
    one = Fraction(1)
    A = _matrix(ex, Fraction(0))
    A = [row[:S] for row in A[:S]]   # the step's stages (the interpolant's are not needed)
    for i in range(S):
        assert sum(A[i], Fraction(0)) == ex['c'][i]
    assert all(r == 0 for r in _residuals(ex['b'], A, 8, one))
    nine = []
    for t in trees(9)[:20]:
        phi = _phi(t, A, one)
        nine.append(sum((ex['b'][i] * phi[i] for i in range(S)), Fraction(0)) - one / _gamma(t))
    assert any(r != 0 for r in nine)
    bh = [bi + ei for bi, ei in zip(ex['b'], ex['e'])]
    res = _residuals(bh, A, 8, one)
    assert all(r == 0 for r in res[:-115]) and any(r != 0 for r in res[-115:])
    assert ex['c'][S - 1] == 1 and list(ex['a'][S - 1]) == list(ex['b'][:S - 1])
    assert ex['b'][S - 1] == 0 and ex['e'][S - 1] == 0


@pytest.mark.parametrize('theta', [Fraction(1, 3), Fraction(4, 5)])
def test_vern8_interpolant_order_8(theta):
    """Verner's continuous extension of the 8(7) pair (eight extra stages, the first one
    f(t + h, y_new); 40-digit decimals up to ~1.4e6) meets every condition of order <= 8 at
    theta to 1e-28 (the decimals' rounding times the coefficients' size)."""
    ex = erk_exact('vern8')
    A = _matrix(ex, Fraction(0))
    bt = [sum((row[d] * theta ** (d + 1) for d in range(len(row))), Fraction(0))
          for row in ex['p']]
    res = _residuals(bt, A, 8, Fraction(1), theta)
    assert max(abs(r) for r in res) < Fraction(1, 10 ** 28)
