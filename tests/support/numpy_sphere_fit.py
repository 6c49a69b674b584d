"""A small independent geometric sphere fit in NumPy (Gauss-Newton from an
algebraic start), used by tests as a reference; no cmmpose import."""

import numpy as np


def fit_sphere_reference(points):
    """Centre (3,) and radius (mm) minimising sum (|p - c| - r)^2."""
    p = np.asarray(points, dtype=float)
    m = p.mean(axis=0)
    q = p - m
    a = np.column_stack([2 * q, np.ones(len(q))])
    x = np.linalg.lstsq(a, (q**2).sum(axis=1), rcond=None)[0]
    c, r = x[:3], np.sqrt(x[3] + x[:3] @ x[:3])
    for _ in range(50):
        d = q - c
        n = np.linalg.norm(d, axis=1)
        jac = np.column_stack([-d / n[:, None], -np.ones(len(n))])
        step = np.linalg.lstsq(jac, -(n - r), rcond=None)[0]
        c, r = c + step[:3], r + step[3]
        if np.abs(step).max() < 1e-13:
            break
    return c + m, r
