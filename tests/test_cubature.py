"""Cubature rules of seed 004: exactness on Gaussian monomials, structure of eq. 22."""
import numpy as np
import pytest

from estimators.cubature import fifth_degree_rule, third_degree_rule

N_MAX = 25


def rule_moment_tensor(points: np.ndarray, weights: np.ndarray, degree: int) -> np.ndarray:
    """T[i1..id] = sum_p w_p x_p[i1] ... x_p[id]: every monomial of degree d at once, (n,)*d.

    Exact scatter over each point's support (its nonzero coordinates, whatever they are), so the
    n^d tensor costs |support|^d per point instead of n^d.
    """
    n = points.shape[0]
    T = np.zeros((n,) * degree)
    if degree == 0:
        return np.array(weights.sum())
    for p in range(points.shape[1]):
        S = np.flatnonzero(points[:, p])
        if S.size == 0:
            continue
        sub = points[S, p]
        outer = sub
        for _ in range(degree - 1):
            outer = np.multiply.outer(outer, sub)
        T[np.ix_(*([S] * degree))] += weights[p] * outer
    return T


def gaussian_moment_tensor(n: int, degree: int) -> np.ndarray:
    """E[x_i1 ... x_id] for x ~ N(0, I_n): zero for odd d, I for d = 2, Isserlis for d = 4."""
    if degree == 0:
        return np.array(1.0)
    if degree % 2 == 1:
        return np.zeros((n,) * degree)
    I = np.eye(n)
    if degree == 2:
        return I
    if degree == 4:
        return (np.einsum("ij,kl->ijkl", I, I) + np.einsum("ik,jl->ijkl", I, I)
                + np.einsum("il,jk->ijkl", I, I))
    raise ValueError(degree)


@pytest.mark.parametrize("n", range(1, N_MAX + 1))
def test_fifth_degree_rule_is_exact_for_every_monomial_up_to_degree_5(n):
    rule = fifth_degree_rule(n)
    assert rule.points.shape == (n, 2 * n * n + 1) and rule.weights.shape == (2 * n * n + 1,)
    for d in range(6):
        T = rule_moment_tensor(rule.points, rule.weights, d)
        G = gaussian_moment_tensor(n, d)
        # round-off only: entries are sums of O(n^2) terms of size <= (n + 2)^(d/2) / (n + 2)^2
        np.testing.assert_allclose(T, G, rtol=0, atol=1e-11 * (n + 2) ** 2, err_msg=f"n={n}, degree {d}")


@pytest.mark.parametrize("n", range(1, N_MAX + 1))
def test_third_degree_rule_is_exact_for_every_monomial_up_to_degree_3(n):
    rule = third_degree_rule(n)
    assert rule.points.shape == (n, 2 * n)
    for d in range(4):
        T = rule_moment_tensor(rule.points, rule.weights, d)
        np.testing.assert_allclose(T, gaussian_moment_tensor(n, d), rtol=0, atol=1e-12 * n, err_msg=f"n={n}, d={d}")


@pytest.mark.parametrize("n", [1, 2, 5, 13, 25])
def test_rules_are_not_exact_one_degree_higher(n):
    """The exactness test has teeth: degree 6 (fifth rule) and degree 4 (third rule) fail."""
    r5 = fifth_degree_rule(n)
    x1_6 = r5.weights @ r5.points[0] ** 6        # E[x1^6] = 15; the rule gives (n + 2)(7 - n) / 2
    assert np.isclose(x1_6, (n + 2) * (7 - n) / 2) and abs(x1_6 - 15.0) > 1.0
    if n >= 2:
        r3 = third_degree_rule(n)
        assert abs(r3.weights @ (r3.points[0] ** 2 * r3.points[1] ** 2) - 1.0) > 0.5   # E[x1^2 x2^2] = 1


def test_fifth_degree_weights_follow_eq_22():
    for n in (3, 4, 5, 21):
        w = fifth_degree_rule(n).weights
        assert np.isclose(w[0], 2 / (n + 2))
        assert np.allclose(w[1:1 + 2 * n * (n - 1)], 1 / (n + 2) ** 2)
        assert np.allclose(w[1 + 2 * n * (n - 1):], (4 - n) / (2 * (n + 2) ** 2))
        assert np.isclose(w.sum(), 1.0)
        assert (w[-1] < 0) == (n > 4)
    pts = fifth_degree_rule(4).points
    # pair points have norm sqrt(n + 2), axis points too
    assert np.allclose(np.linalg.norm(pts[:, 1:], axis=0), np.sqrt(6.0))


def test_rules_are_read_only():
    r = fifth_degree_rule(3)
    with pytest.raises(ValueError):
        r.points[0, 0] = 1.0
