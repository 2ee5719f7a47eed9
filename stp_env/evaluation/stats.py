"""Exact binomial confidence bounds (Clopper and Pearson, 1934) from the regularized incomplete beta function.

With ``k`` successes in ``n`` independent trials, the exact one-sided upper bound at confidence ``1 - alpha`` is the
``p`` for which seeing ``k`` or fewer successes has probability ``alpha``:

    P(X <= k | n, p_u) = I_{1 - p_u}(n - k, k + 1) = alpha,   i.e.   p_u = B^{-1}(1 - alpha; k + 1, n - k)

(``B^{-1}`` the quantile of the beta distribution; ``p_u = 1`` when ``k = n``). With no success, ``p_u = 1 -
alpha^(1/n)`` (about ``3 / n`` at 95 %: the "rule of three"). The lower bound is ``B^{-1}(alpha; k, n - k + 1)``
(0 when ``k = 0``). A two-sided interval at ``1 - alpha`` uses ``alpha / 2`` on each side.

Pure Python (``math.lgamma`` and a continued fraction), so that the package needs no scipy; the tests compare it
with ``scipy.stats.beta.ppf``.
"""

from __future__ import annotations

import math

_EPS = 1e-15
_TINY = 1e-300


def _check(k: int, n: int, confidence: float) -> None:
    for name, value in (("k", k), ("n", n)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise ValueError(f"{name} must be an integer >= 0; got {value!r}.")
    if n == 0:
        raise ValueError("n must be >= 1 (no trials give no bound).")
    if k > n:
        raise ValueError(f"k must be <= n; got k = {k}, n = {n}.")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1); got {confidence!r}.")


def _beta_continued_fraction(a: float, b: float, x: float) -> float:
    """The continued fraction of ``I_x(a, b)`` (modified Lentz), convergent for ``x < (a + 1) / (a + b + 2)``."""
    qab, qap, qam = a + b, a + 1.0, a - 1.0
    c, d = 1.0, 1.0 - qab * x / qap
    d = 1.0 / (d if abs(d) > _TINY else _TINY)
    h = d
    for m in range(1, 10_000):
        m2 = 2 * m
        for num in (m * (b - m) * x / ((qam + m2) * (a + m2)), -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))):
            d = 1.0 + num * d
            d = 1.0 / (d if abs(d) > _TINY else _TINY)
            c = 1.0 + num / c
            c = c if abs(c) > _TINY else _TINY
            h *= d * c
        if abs(d * c - 1.0) < _EPS:
            return h
    raise ArithmeticError(f"incomplete beta continued fraction did not converge (a={a}, b={b}, x={x}).")


def betainc(a: float, b: float, x: float) -> float:
    """The regularized incomplete beta function ``I_x(a, b)`` for ``a, b > 0``, ``0 <= x <= 1``."""
    if not (a > 0 and b > 0):
        raise ValueError(f"a and b must be > 0; got {a}, {b}.")
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    log_front = math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log1p(-x)
    if x < (a + 1.0) / (a + b + 2.0):
        return math.exp(log_front) * _beta_continued_fraction(a, b, x) / a
    return 1.0 - math.exp(log_front) * _beta_continued_fraction(b, a, 1.0 - x) / b


def beta_ppf(q: float, a: float, b: float) -> float:
    """The ``q``-quantile of the beta distribution ``Beta(a, b)``: the ``x`` with ``I_x(a, b) = q`` (bisection to
    the float resolution; ``I_x`` increases in ``x``)."""
    if not 0.0 <= q <= 1.0:
        raise ValueError(f"q must be in [0, 1]; got {q}.")
    lo, hi = 0.0, 1.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if mid in (lo, hi):
            break
        if betainc(a, b, mid) < q:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def clopper_pearson_upper(k: int, n: int, confidence: float = 0.95) -> float:
    """Exact one-sided upper bound on a binomial probability after ``k`` successes in ``n`` trials."""
    _check(k, n, confidence)
    if k == n:
        return 1.0
    if k == 0:
        return -math.expm1(math.log(1.0 - confidence) / n)   # 1 - alpha^(1/n), exactly
    return beta_ppf(confidence, k + 1, n - k)


def clopper_pearson_lower(k: int, n: int, confidence: float = 0.95) -> float:
    """Exact one-sided lower bound on a binomial probability after ``k`` successes in ``n`` trials."""
    _check(k, n, confidence)
    if k == 0:
        return 0.0
    if k == n:
        return math.exp(math.log(1.0 - confidence) / n)       # alpha^(1/n)
    return beta_ppf(1.0 - confidence, k, n - k + 1)


def clopper_pearson_interval(k: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Exact two-sided interval at ``confidence`` (``(1 - confidence) / 2`` in each tail)."""
    tail = 1.0 - (1.0 - confidence) / 2.0
    return clopper_pearson_lower(k, n, tail), clopper_pearson_upper(k, n, tail)
