"""Exact rigid-body "truth machine" for a moving-bridge X-Y-Z CMM (pure NumPy).

Given one error map (same dict as ``numpy_reference``: tables in mm / um / arc-seconds,
squareness in arc-seconds), ``true_points`` returns where the scanned points really are
when the machine has exactly those errors.  No small-angle shortcut is taken anywhere:

* each carriage A in {X, Y, Z} is rotated by R_A = Rz(ez(A)) @ Ry(ey(A)) @ Rx(ex(A)) of
  its interpolated angles (right-hand rule about the machine axes) and displaced by its
  interpolated deltas d(A) = [dx(A), dy(A), dz(A)];
* the Y guideway points along y_dir = unit(-tan S_xy, 1, 0) and the Z guideway along
  z_dir = unit(-tan S_zx, -tan S_yz, 1);
* kinematic chain (X on the table carries the bridge Y, which carries the ram Z):

      P = [D, 0, 0] + d(X) + R_X @ ( E*y_dir + d(Y) + R_Y @ ( F*z_dir + d(Z) ) )
      X_true = P + R_X @ R_Y @ R_Z @ E313 @ ((u, v, 0) - l1)

Agreement with eqs. 11-13 to first order: with R_A = I + [eps_A]x + O(eps^2),
y_dir = (-S_xy, 1, 0) + O(S^2), z_dir = (-S_zx, -S_yz, 1) + O(S^2),

      P - S = sum_A d(A) + (-E S_xy - F S_zx, -F S_yz, 0)
              + eps_X x (0, E, F) + eps_Y x (0, 0, F) + O(2)
      eps_X x (0, E, F) = (F ey(X) - E ez(X), -F ex(X), E ex(X))
      eps_Y x (0, 0, F) = (F ey(Y),          -F ex(Y), 0     )

which is e(S) of eqs. 11-13 term by term, and R_X R_Y R_Z = I + [eps_X + eps_Y + eps_Z]x
+ O(2) matches R(S) of eqs. 26-31 (right-handed X_p) to first order.  The compensation
X_H = S + e(S) + R(S) E313 ((u, v, 0) - l1) therefore reproduces this chain up to a
remainder of second order in the angles (angle^2 x lever/travel, squareness^2 x travel,
angle x squareness x travel, angle x delta); a sign error in any first-order term (e.g.
the printed eq. 30, which rotates by -eps_Z) shows up at first order instead.
"""

import numpy as np

from numpy_reference import ARCSEC_TO_RAD, euler313, interpolate_carriage


def _rot(axis, angle):
    """(N, 3, 3) proper rotations by ``angle`` (N,) rad about machine axis 0, 1 or 2."""
    c, s = np.cos(angle), np.sin(angle)
    i, j = (axis + 1) % 3, (axis + 2) % 3
    r = np.zeros((len(angle), 3, 3))
    r[:, axis, axis] = 1.0
    r[:, i, i], r[:, j, j] = c, c
    r[:, j, i], r[:, i, j] = s, -s   # right-hand rule: e_i -> c e_i + s e_j
    return r


def _carriage_rotation(eps):
    """R_A = Rz(ez) @ Ry(ey) @ Rx(ex) for eps (N, 3) rad."""
    return _rot(2, eps[:, 2]) @ _rot(1, eps[:, 1]) @ _rot(0, eps[:, 0])


def _unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def true_points(uv, scales, map_dict, pose, offset):
    """True machine coordinates (N, 3) mm of the scanned points for the errors in ``map_dict``."""
    scales = np.atleast_2d(np.asarray(scales, dtype=float))
    uv = np.atleast_2d(np.asarray(uv, dtype=float))
    D, E, F = scales.T
    vals = {a: interpolate_carriage(map_dict[a], scales[:, k]) for k, a in enumerate("XYZ")}
    d = {a: v[:, :3] for a, v in vals.items()}                      # mm
    R = {a: _carriage_rotation(v[:, 3:]) for a, v in vals.items()}  # from rad

    s_xy, s_yz, s_zx = np.asarray(map_dict["squareness"], dtype=float) * ARCSEC_TO_RAD
    y_dir = _unit([-np.tan(s_xy), 1.0, 0.0])
    z_dir = _unit([-np.tan(s_zx), -np.tan(s_yz), 1.0])

    mv = lambda m, v: np.einsum("nij,nj->ni", m, v)
    ram = F[:, None] * z_dir + d["Z"]
    bridge = E[:, None] * y_dir + d["Y"] + mv(R["Y"], ram)
    p = np.column_stack([D, np.zeros_like(D), np.zeros_like(D)]) + d["X"] + mv(R["X"], bridge)

    local = np.column_stack([uv[:, 0], uv[:, 1], np.zeros(len(uv))]) - np.asarray(offset, float)
    lever = local @ euler313(*pose).T
    return p + mv(R["X"] @ R["Y"] @ R["Z"], lever)


def second_order_bound(uv, scales, map_dict, pose, offset):
    """Per-point upper bound (N,) mm on |true_points - first-order compensation|.

    Every term the compensation leaves out is of second order in the small quantities:
    a = sum of |eps| over the 9 carriage angles at the point, s = |S_xy| + |S_yz| + |S_zx|
    (rad), delta = sum over carriages of |d(A)| (mm), L = |E| + |F| + |lever| (mm):

        |remainder| <= (a + s)^2 * L + a * delta

    ((a + s)^2 covers angle^2, angle x squareness and the squareness cosines E*S^2/2,
    F*S^2/2 that eqs. 11-12 do not model; a*delta the rotation of the deltas.)
    """
    scales = np.atleast_2d(np.asarray(scales, dtype=float))
    uv = np.atleast_2d(np.asarray(uv, dtype=float))
    vals = [interpolate_carriage(map_dict[a], scales[:, k]) for k, a in enumerate("XYZ")]
    a = sum(np.abs(v[:, 3:]).sum(axis=1) for v in vals)
    delta = sum(np.linalg.norm(v[:, :3], axis=1) for v in vals)
    s = np.abs(np.asarray(map_dict["squareness"], dtype=float)).sum() * ARCSEC_TO_RAD
    local = np.column_stack([uv[:, 0], uv[:, 1], np.zeros(len(uv))]) - np.asarray(offset, float)
    L = np.abs(scales[:, 1]) + np.abs(scales[:, 2]) + np.linalg.norm(local, axis=1)
    return (a + s) ** 2 * L + a * delta
