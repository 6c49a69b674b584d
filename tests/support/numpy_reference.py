"""Pure-NumPy reference implementation of the per-point compensation model.

This module restates chapter 5 of the thesis (eqs. 7, 10-13, 25-35) with the conventions
of docs/conventions.md (Frames, The compensation, Misprints), written directly from the
equations.  It is deliberately independent of the Rust kernel (it does not import
``cmmpose`` and shares no code with it) so that the kernel can be checked against it.

Units
-----
* Map tables, (n, 7) per carriage: column 0 position in mm (strictly increasing),
  columns 1-3 delta_x, delta_y, delta_z in micrometres, columns 4-6 eps_x, eps_y, eps_z
  in arc-seconds.  Squareness (S_xy, S_yz, S_zx) in arc-seconds.
* Everything returned is in mm and radians: the conversion happens only in
  ``_COLUMN_SCALE`` / ``ARCSEC_TO_RAD`` below (um -> mm is /1000,
  arc-second -> rad is * pi/648000).
* Scale readings D, E, F and scan-plane coordinates u, v in mm; pose angles in degrees.

A map is ``{"temperature": float | None, "X": arr, "Y": arr, "Z": arr,
"squareness": (s_xy, s_yz, s_zx)}``.
"""

import numpy as np

UM_TO_MM = 1e-3
ARCSEC_TO_RAD = np.pi / 648000.0
# per-column factor for the six error columns of a carriage table -> mm, mm, mm, rad, rad, rad
_COLUMN_SCALE = np.array([UM_TO_MM] * 3 + [ARCSEC_TO_RAD] * 3)

AXES = ("X", "Y", "Z")


def euler313(alpha, beta, gamma):
    """Euler 3-1-3 matrix (eq. 7), angles in degrees; columns are u, v, w in machine axes."""
    a, b, g = np.radians([alpha, beta, gamma])
    ca, sa, cb, sb, cg, sg = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(g), np.sin(g)
    return np.array([
        [ca * cg - sa * cb * sg, -ca * sg - sa * cb * cg, sa * sb],
        [ca * cb * sg + sa * cg, ca * cb * cg - sa * sg, -ca * sb],
        [sb * sg, sb * cg, cb],
    ])


def interpolate_carriage(table, positions):
    """Linear interpolation of the 6 error columns of one carriage table -> (N, 6) mm / rad.

    Raises ValueError for positions outside [table[0, 0], table[-1, 0]] (no clamping).
    """
    table = np.asarray(table, dtype=float)
    p = np.atleast_1d(np.asarray(positions, dtype=float))
    if table.ndim != 2 or table.shape[1] != 7 or len(table) < 1:
        raise ValueError(f"carriage table must be (n, 7), got {table.shape}")
    x, y = table[:, 0], table[:, 1:] * _COLUMN_SCALE
    if np.any(np.diff(x) <= 0):
        raise ValueError("carriage table positions must be strictly increasing")
    if not np.all((p >= x[0]) & (p <= x[-1])):  # also rejects NaN
        raise ValueError(f"position outside map range [{x[0]}, {x[-1]}] mm")
    if len(x) == 1:
        return np.repeat(y, len(p), axis=0)
    i = np.clip(np.searchsorted(x, p, side="right") - 1, 0, len(x) - 2)
    t = ((p - x[i]) / (x[i + 1] - x[i]))[:, None]
    return (1.0 - t) * y[i] + t * y[i + 1]


def _map_components(m, scales):
    """21 components of one map at the scale readings: (N, 3, 6) carriage values (rows X, Y, Z
    carriages interpolated at D, E, F) and (N, 3) squareness, mm / rad."""
    carr = np.stack([interpolate_carriage(m[a], scales[:, k]) for k, a in enumerate(AXES)], axis=1)
    sq = np.broadcast_to(np.asarray(m["squareness"], dtype=float) * ARCSEC_TO_RAD, (len(scales), 3))
    return carr, sq


def blend_maps(maps, temperature):
    """Return ``components(scales) -> (carriage (N, 3, 6), squareness (N, 3))``, mm / rad.

    ``maps`` is one map dict or a list.  ``temperature`` None: exactly one map, used as is.
    Otherwise (a float or an (N,) array, one per point): maps sorted by temperature, a
    temperature equal to a map's uses that map, else the two bracketing maps are
    interpolated at the points and combined with w = (T - T_lo) / (T_hi - T_lo), all 21
    components.  T outside [min, max] -> ValueError.
    """
    maps = [maps] if isinstance(maps, dict) else list(maps)
    if not maps:
        raise ValueError("no maps")
    if temperature is None:
        if len(maps) != 1:
            raise ValueError("several maps given: a temperature is required")
        return lambda scales: _map_components(maps[0], _as_scales(scales))

    if any(m.get("temperature") is None for m in maps):
        raise ValueError("every map needs a temperature to blend by temperature")
    maps = sorted(maps, key=lambda m: m["temperature"])
    temps = np.array([m["temperature"] for m in maps], dtype=float)
    if np.any(np.diff(temps) <= 0):
        raise ValueError("duplicate map temperatures")

    def components(scales):
        scales = _as_scales(scales)
        t = np.broadcast_to(np.asarray(temperature, dtype=float), (len(scales),))
        if not np.all((t >= temps[0]) & (t <= temps[-1])):
            raise ValueError(f"temperature outside map range [{temps[0]}, {temps[-1]}] C")
        per_map = [_map_components(m, scales) for m in maps]  # loop over maps, not points
        carr = np.stack([c for c, _ in per_map])               # (K, N, 3, 6)
        sq = np.stack([s for _, s in per_map])                 # (K, N, 3)
        if len(maps) == 1:
            return carr[0], sq[0]
        lo = np.clip(np.searchsorted(temps, t, side="right") - 1, 0, len(temps) - 2)
        w = (t - temps[lo]) / (temps[lo + 1] - temps[lo])   # 0 or 1 exactly at a map temperature
        n = np.arange(len(scales))

        def blend(a):  # a: (K, N, ...) -> (N, ...)
            ww = w.reshape((-1,) + (1,) * (a.ndim - 2))
            return (1.0 - ww) * a[lo, n] + ww * a[lo + 1, n]

        return blend(carr), blend(sq)

    return components


def _as_scales(scales):
    s = np.atleast_2d(np.asarray(scales, dtype=float))
    if s.shape[1] != 3:
        raise ValueError(f"scales must be (N, 3), got {s.shape}")
    return s


def _position_error(carr, sq, scales):
    """Eqs. 11-13; carr (N, 3 carriages, 6), sq (N, 3) in mm / rad."""
    E, F = scales[:, 1], scales[:, 2]
    d = carr[:, :, :3].sum(axis=1)               # sum over carriages of delta_x, delta_y, delta_z
    ex, ey, ez = (carr[:, :, 3 + j] for j in range(3))   # (N, 3): column k = carriage X, Y, Z
    s_xy, s_yz, s_zx = sq.T
    e_x = d[:, 0] - E * ez[:, 0] + F * ey[:, 0] + F * ey[:, 1] - E * s_xy - F * s_zx
    e_y = d[:, 1] - F * ex[:, 1] - F * ex[:, 0] - F * s_yz
    e_z = d[:, 2] + E * ex[:, 0]
    return np.stack([e_x, e_y, e_z], axis=1)


def _rotation_error(carr):
    """Eqs. 26-31 with the right-handed X_p of docs/conventions.md (eq. 30); columns X_p, Y_p, Z_p."""
    tx, ty, tz = np.tan(carr[:, :, 3:].sum(axis=1)).T     # eps_X, eps_Y, eps_Z totals
    one = np.ones_like(tx)
    zp = np.stack([ty, -tx, one], axis=1)
    xp = np.stack([one, tz, tx * tz - ty], axis=1)
    zp /= np.linalg.norm(zp, axis=1, keepdims=True)
    xp /= np.linalg.norm(xp, axis=1, keepdims=True)
    yp = np.cross(zp, xp)
    return np.stack([xp, yp, zp], axis=2)


def position_error(map_or_maps, scales, temperature=None):
    """e(S) of eqs. 11-13, (N, 3) mm."""
    scales = _as_scales(scales)
    carr, sq = blend_maps(map_or_maps, temperature)(scales)
    return _position_error(carr, sq, scales)


def rotation_error(map_or_maps, scales, temperature=None):
    """R(S), (N, 3, 3), columns X_p, Y_p, Z_p (eqs. 26-31, right-handed X_p)."""
    carr, _ = blend_maps(map_or_maps, temperature)(_as_scales(scales))
    return _rotation_error(carr)


def _lever(uv, pose, offset):
    """E313 @ ((u, v, 0) - l1) per point, (N, 3) mm."""
    uv = np.atleast_2d(np.asarray(uv, dtype=float))
    local = np.column_stack([uv[:, 0], uv[:, 1], np.zeros(len(uv))]) - np.asarray(offset, float)
    return local @ euler313(*pose).T


def compensate(uv, scales, maps, pose, offset, temperature=None):
    """X_H = S + e(S) + R(S) @ E313 @ ((u, v, 0) - l1), (N, 3) mm."""
    scales = _as_scales(scales)
    carr, sq = blend_maps(maps, temperature)(scales)
    lever = _lever(uv, pose, offset)
    return scales + _position_error(carr, sq, scales) + np.einsum("nij,nj->ni", _rotation_error(carr), lever)


def uncompensated(uv, scales, pose, offset):
    """X_H = S + E313 @ ((u, v, 0) - l1), (N, 3) mm (what the digitizer software reports)."""
    return _as_scales(scales) + _lever(uv, pose, offset)
