"""The few splines the simulator and the search need, in NumPy: B-splines, cubic interpolation, smoothing.

``scipy.interpolate`` did this, but importing it costs ~0.8 s of CPU (it pulls in ``scipy.optimize``,
``scipy.special``, ``scipy.sparse``, ...): more than a third of a 2,000-variant search of KITTI 0003,
every search process paying it before any simulation starts. These give SciPy's results to rounding
(the tests compare them with SciPy):

* :class:`BSpline`: ``scipy.interpolate.BSpline(t, c, k)`` evaluated inside its base interval;
* :func:`interp_spline`: ``make_interp_spline(x, y, k)`` for k = 1 and k = 3 (not-a-knot);
* :func:`lsq_spline`: ``make_lsq_spline(x, y, t, k)``;
* :func:`smoothing_spline`: ``make_smoothing_spline(x, y, lam=lam)`` (a natural cubic spline, Reinsch's form).

``x`` is any increasing abscissa (seconds for the simulator); ``y`` has the samples on its first axis.
The linear systems (a few hundred unknowns) are solved by LAPACK on one thread: OpenBLAS' threads made a
182 x 182 solve take 100-300 ms instead of 3 ms on a loaded 2-core machine (they wait for each other).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np


@functools.cache
def _controller() -> Any:
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


def one_thread() -> Any:
    """A context in which the BLAS/LAPACK libraries run on one thread."""
    return _controller().limit(limits=1, user_api="blas")


def local_basis(t: np.ndarray, k: int, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ``k + 1`` B-spline basis functions that are non-zero at each ``x`` (de Boor's recurrence).

    Returns ``span`` (L,) and ``values`` (L, k + 1): at ``x[l]`` basis function ``span[l] - k + a`` is
    ``values[l, a]``. ``x`` is clamped to the base interval ``[t[k], t[-k-1]]`` (its right end included).
    """
    t = np.asarray(t, float)
    x = np.clip(np.asarray(x, float), t[k], t[len(t) - k - 1])
    m = len(t) - k - 1
    span = np.clip(np.searchsorted(t, x, side="right") - 1, k, m - 1)
    values = np.zeros((len(x), k + 1))
    values[:, 0] = 1.0
    left = np.empty((len(x), k + 1))
    right = np.empty((len(x), k + 1))
    for j in range(1, k + 1):
        left[:, j] = x - t[span + 1 - j]
        right[:, j] = t[span + j] - x
        saved = np.zeros(len(x))
        for r in range(j):
            den = right[:, r + 1] + left[:, j - r]
            with np.errstate(divide="ignore", invalid="ignore"):
                temp = np.where(den != 0.0, values[:, r] / den, 0.0)
            values[:, r] = saved + right[:, r + 1] * temp
            saved = left[:, j - r] * temp
        values[:, j] = saved
    return span, values


def basis_matrix(t: np.ndarray, k: int, x: np.ndarray) -> np.ndarray:
    """(L, m) dense matrix of all ``m = len(t) - k - 1`` basis functions at ``x``."""
    span, values = local_basis(t, k, x)
    out = np.zeros((len(span), len(t) - k - 1))
    rows = np.arange(len(span))
    for a in range(k + 1):
        out[rows, span - k + a] = values[:, a]
    return out


@dataclass(frozen=True)
class BSpline:
    """``sum_i c[i] B_{i,k}(x)`` on knots ``t``; ``c`` (m, ...) may carry trailing dimensions (many curves)."""

    t: np.ndarray
    c: np.ndarray
    k: int

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """Values at ``x`` (clamped to the base interval): (len(x), ...)."""
        x = np.atleast_1d(np.asarray(x, float))
        span, values = local_basis(self.t, self.k, x)
        c = np.asarray(self.c, float)
        c2 = c.reshape(len(c), -1)
        if c2.shape[1] >= 64 and len(x) > 1 and bool((np.diff(span) >= 0).all()):
            return _grouped(span, values, c2, self.k).reshape(len(x), *c.shape[1:])
        out = np.zeros((len(span), c2.shape[1]))
        for a in range(self.k + 1):
            out += values[:, a, None] * c2[span - self.k + a]
        return out.reshape(len(x), *c.shape[1:])

    def derivative(self, nu: int = 1) -> BSpline:
        """The ``nu``-th derivative, a spline of degree ``k - nu`` on ``t[nu:-nu]``."""
        sp = self
        for _ in range(nu):
            sp = sp._derivative()
        return sp

    def _derivative(self) -> BSpline:
        t, c, k = np.asarray(self.t, float), np.asarray(self.c, float), self.k
        if k == 0:
            return BSpline(t, np.zeros_like(c), 0)
        m = len(t) - k - 1
        den = (t[k + 1 : k + m] - t[1:m])[(slice(None),) + (None,) * (c.ndim - 1)]
        with np.errstate(divide="ignore", invalid="ignore"):
            dc = np.where(den > 0.0, k * (c[1:] - c[:-1]) / den, 0.0)
        return BSpline(t[1:-1], dc, k - 1)


def _grouped(span: np.ndarray, values: np.ndarray, c: np.ndarray, k: int) -> np.ndarray:
    """``sum_a values[:, a] * c[span - k + a]`` for many columns of ``c`` (m, C) at increasing ``span``: the
    points of each knot interval as one small matrix product with the interval's ``k + 1`` coefficient rows."""
    spans, first, count = np.unique(span, return_index=True, return_counts=True)
    g = int(count.max())
    slot = np.arange(len(span)) - np.repeat(first, count)  # position within its interval
    group = np.repeat(np.arange(len(spans)), count)
    v = np.zeros((len(spans), g, k + 1))
    v[group, slot] = values
    window = np.lib.stride_tricks.sliding_window_view(c, k + 1, axis=0)  # (m - k, C, k + 1), no copy
    lo = int(spans[0]) - k
    # consecutive intervals (the usual case: samples everywhere): their windows as a slice, not a gathered copy
    rows = window[lo : lo + len(spans)] if int(spans[-1]) - k - lo == len(spans) - 1 else window[spans - k]
    out = np.matmul(v, rows.transpose(0, 2, 1))  # (intervals, g, C)
    return out.reshape(len(spans) * g, -1)[group * g + slot]


def not_a_knot(x: np.ndarray, k: int = 3) -> np.ndarray:
    """Knots of the not-a-knot interpolating spline of odd degree ``k`` through abscissae ``x`` (SciPy's)."""
    h = (k + 1) // 2
    return np.r_[(x[0],) * (k + 1), x[h:-h], (x[-1],) * (k + 1)]


def interp_spline(x: np.ndarray, y: np.ndarray, k: int = 3) -> BSpline:
    """The spline of degree ``k`` (1 or 3; 3: not-a-knot) through ``y`` (n, ...) at increasing ``x`` (n,)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    if k == 1:
        return BSpline(np.r_[x[0], x, x[-1]], y, 1)
    if k != 3 or len(x) < 4:
        raise ValueError(f"interp_spline: degree {k} with {len(x)} samples (needs k = 1, or k = 3 and >= 4)")
    t = not_a_knot(x, 3)
    a = basis_matrix(t, 3, x)
    with one_thread():
        c = np.linalg.solve(a, y.reshape(len(x), -1)).reshape(y.shape)
    return BSpline(t, c, 3)


def interp_inverse(x: np.ndarray) -> np.ndarray:
    """(n, n) inverse of the collocation matrix of the not-a-knot cubic spline at ``x`` (n,): its coefficients on
    knots ``not_a_knot(x)`` are ``inverse @ y`` (one matrix product for thousands of curves sampled at ``x``)."""
    x = np.asarray(x, float)
    with one_thread():
        return np.linalg.solve(basis_matrix(not_a_knot(x, 3), 3, x), np.eye(len(x)))


def lsq_spline(x: np.ndarray, y: np.ndarray, t: np.ndarray, k: int = 3) -> BSpline:
    """The least-squares spline of degree ``k`` on knots ``t`` through samples ``y`` (n, ...) at ``x`` (n,)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    a = basis_matrix(t, k, x)
    with one_thread():
        c = np.linalg.lstsq(a, y.reshape(len(x), -1), rcond=None)[0]
    return BSpline(np.asarray(t, float), c.reshape((a.shape[1], *y.shape[1:])), k)


@dataclass(frozen=True)
class NaturalCubic:
    """A natural cubic spline by its values ``g`` (n, ...) and second derivatives ``gamma`` (n, ...) at knots ``x``."""

    x: np.ndarray
    g: np.ndarray
    gamma: np.ndarray
    nu: int = 0  # derivative evaluated (0 or 1)

    def __call__(self, xq: np.ndarray) -> np.ndarray:
        x = self.x
        xq = np.clip(np.atleast_1d(np.asarray(xq, float)), x[0], x[-1])
        i = np.clip(np.searchsorted(x, xq, side="right") - 1, 0, len(x) - 2)
        extra = (slice(None),) + (None,) * (self.g.ndim - 1)
        h = (x[i + 1] - x[i])[extra]
        a = ((x[i + 1] - xq) / (x[i + 1] - x[i]))[extra]
        b = 1.0 - a
        g0, g1, c0, c1 = self.g[i], self.g[i + 1], self.gamma[i], self.gamma[i + 1]
        if self.nu == 0:
            return a * g0 + b * g1 + ((a**3 - a) * c0 + (b**3 - b) * c1) * (h * h / 6.0)
        return (g1 - g0) / h + (-(3.0 * a * a - 1.0) * c0 + (3.0 * b * b - 1.0) * c1) * (h / 6.0)

    def derivative(self) -> NaturalCubic:
        if self.nu:
            raise ValueError("NaturalCubic evaluates its value and first derivative only")
        return NaturalCubic(self.x, self.g, self.gamma, 1)


def smoothing_spline(x: np.ndarray, y: np.ndarray, lam: float) -> NaturalCubic:
    """The cubic smoothing spline minimising ``sum (y_i - f(x_i))^2 + lam * integral f''(u)^2 du`` (n >= 5).

    Reinsch's algorithm (Green & Silverman, 1994, section 2.3.3): ``(R + lam Q^T Q) gamma = Q^T y`` for the
    second derivatives at the interior knots, values ``g = y - lam Q gamma``; SciPy's
    ``make_smoothing_spline(x, y, lam=lam)`` to rounding.
    """
    x, y = np.asarray(x, float), np.asarray(y, float)
    n = len(x)
    if n < 5:
        raise ValueError(f"smoothing_spline needs >= 5 samples (got {n})")
    h = np.diff(x)
    q = np.zeros((n, n - 2))
    j = np.arange(n - 2)
    q[j, j] = 1.0 / h[:-1]
    q[j + 1, j] = -1.0 / h[:-1] - 1.0 / h[1:]
    q[j + 2, j] = 1.0 / h[1:]
    r = np.zeros((n - 2, n - 2))
    r[j, j] = (h[:-1] + h[1:]) / 3.0
    r[j[:-1], j[:-1] + 1] = r[j[:-1] + 1, j[:-1]] = h[1:-1] / 6.0
    y2 = y.reshape(n, -1)
    with one_thread():
        gamma_in = np.linalg.solve(r + lam * (q.T @ q), q.T @ y2)
        g = y2 - lam * (q @ gamma_in)
    gamma = np.zeros_like(g)
    gamma[1:-1] = gamma_in
    return NaturalCubic(x, g.reshape(y.shape), gamma.reshape(y.shape))
