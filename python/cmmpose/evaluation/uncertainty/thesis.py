"""The thesis's uncertainty budgets as code (mount offset, a sphere's centre, a ballbar length), with the values
it printed to check them against. Thesis references are to section and line of its plain text (data/SOURCES.md);
values in um.
"""

from __future__ import annotations

import math

import numpy as np

from ..._arrays import as_triple
from ..._validate import finite
from ...errors import InputError
from .gum import Budget, Input

THESIS = "J. O. Harris, PhD thesis (McMaster)"


#: Worst-case scale errors (um, X, Y, Z) over a 404 mm length at each map
#: temperature, thesis section 6.4.1, lines 1751-1753.
THESIS_SCALE_ERRORS_UM: dict[float, tuple[float, float, float]] = {
    20.0: (12.0, 18.0, 6.0),
    25.0: (21.0, 30.0, 12.0),
    30.0: (26.0, 38.0, 20.0),
}

# Combined standard uncertainties the thesis prints (um), keyed as used below.
_PRINTED_OFFSET = {"U1": 35.1, "V1": 35.1, "W1": 39.9}  # eqs. 22-24, lines 1467, 1473, 1481
_PRINTED_LENGTH = {
    # (compensated, temperature or None, n_positions) -> um
    (True, None, 1): 20.0,   # 6.2.3, lines 1625, 1635, 1637
    (True, None, 8): 7.0,    # 6.2.3, line 1637; 404.084 +- 0.007 mm, line 1681
    (True, None, 20): 5.0,   # 6.3.1 "22 +- 5 um" line 1661; Tables 19 and 21, lines 1736-1738, 1763-1765
    (True, None, 60): 3.0,   # Table 19 all temperatures, line 1739; Table 21, line 1766 (0.005/sqrt(3), line 1772)
    (False, 20.0, 1): 26.0,  # 6.4.1, line 1753; 6.2.3, lines 1623, 1633
    (False, 25.0, 1): 41.0,  # 6.4.1, line 1753
    (False, 30.0, 1): 52.0,  # 6.4.1, line 1753
    (False, 20.0, 20): 6.0,  # Tables 19 and 21, lines 1736, 1763; 6.3.1 "71 +- 6 um" line 1661
    (False, 25.0, 20): 10.0,  # Tables 19 and 21, lines 1737, 1764
    (False, 30.0, 20): 12.0,  # Tables 19 and 21, lines 1738, 1765
}


def _reading(label: str, scale_axis: str, digitizer: float, fit_per_axis: float, scale: float, c: float) -> list[Input]:
    """The three error terms of one scale reading of an alignment (section 5.3, lines 1452-1458)."""
    return [
        Input(f"{label}: digitizer probing", 0.0, digitizer, "um", c, "Hyscan 45C probing uncertainty, 1 sigma (Table 17, line 1268)"),
        Input(f"{label}: sphere-centre fit", 0.0, fit_per_axis, "um", c, "10 um per centre spread over 3 axes: 10/sqrt(3) (line 1452)"),
        Input(f"{label}: {scale_axis} scale error", 0.0, scale, "um", c, "scale error over the range used (lines 1452, 1456)"),
    ]


def mount_offset_budgets(*, digitizer: float = 9.0, sphere_fit: float = 10.0, scale=(2.0, 16.5, 1.0),
                         model: str = "printed") -> dict[str, Budget]:
    """Uncertainty budgets of the mount offset U1, V1, W1 (thesis section 5.3, eqs. 19-24).

    Every scale reading D, E, F of an alignment carries three uncorrelated error
    terms: the digitizer's probing uncertainty, the sphere-centre fit's share
    per axis (``sphere_fit``/sqrt(3)) and that axis's scale error.

    Parameters
    ----------
    digitizer : float
        Digitizer probing uncertainty, um (thesis: 9).
    sphere_fit : float
        Sphere-centre fit uncertainty, um, as a 3-D value (thesis: 10; 10/sqrt(3)
        per axis, printed as 5.8).
    scale : sequence of 3 float
        Scale error of the X, Y, Z scale over the range used, um (thesis: 2, 16.5, 1).
    model : {'printed', 'corrected'}
        ``'printed'``: U1 and V1 from eqs. 19-20 (eqs. 22-23); W1 as eq. 24 is
        numbered, 5/4 u^2(D1) + 1/4 u^2(E1) + u^2(F1) (the form the thesis puts
        numbers into). ``'corrected'``: W1 = D1 - D3 - U1 (eq. 21 is
        misprinted: docs/conventions.md, Misprints), propagated from its six
        readings. U1 and V1 are the same.

    Returns
    -------
    dict
        ``{"U1": Budget, "V1": Budget, "W1": Budget}`` in um. Each budget's
        ``printed`` is the value the thesis prints (35.1, 35.1, 39.9 um), which
        eqs. 22-24 as printed do not give: they give 15.8, 15.8 and 19.0 um
        (docs/uncertainty.md, "The mount-offset figures").
    """
    dig = finite("digitizer", digitizer)
    fit = finite("sphere_fit", sphere_fit)
    sx, sy, sz = as_triple("scale", scale)
    if min(dig, fit, sx, sy, sz) < 0:
        raise InputError("digitizer, sphere_fit, scale: uncertainties must be >= 0 (um)")
    if model not in ("printed", "corrected"):
        raise InputError(f"model: expected 'printed' or 'corrected', got {model!r}")
    per_axis = fit / math.sqrt(3.0)
    axis = {"D": ("X", sx), "E": ("Y", sy), "F": ("Z", sz)}

    def reading(name: str, c: float) -> list[Input]:
        a, s = axis[name[0]]
        return _reading(name, a, dig, per_axis, s, c)

    src = "thesis section 5.3"
    u1 = [*reading("E1", 0.5), *reading("E2", -0.5), *reading("F2", 0.5), *reading("F1", -0.5)]
    v1 = [*reading("E1", 0.5), *reading("E2", -0.5), *reading("F1", 0.5), *reading("F2", -0.5)]
    if model == "printed":
        # Eq. 24 as numbered (line 1479): 5/4 u^2(D1) + 1/4 u^2(E1) + u^2(F1), i.e. effective
        # coefficients sqrt(5)/2, 1/2 and 1 on one reading of each axis.
        w1 = [*reading("D1 (x5/4 in variance)", math.sqrt(5.0) / 2), *reading("E1 (x1/4)", 0.5), *reading("F1 (x1)", 1.0)]
        w_src = f"{src}, eq. 24 as numbered, lines 1475-1481"
    else:
        w1 = [*reading("D1", 1.0), *reading("D3", -1.0), *reading("E1", -0.5), *reading("E2", 0.5),
              *reading("F2", -0.5), *reading("F1", 0.5)]
        w_src = f"{src}, W1 = D1 - D3 - U1 (eqs. 16, 18, 19; docs/conventions.md, Misprints)"
    return {
        "U1": Budget("U1", tuple(u1), "um", f"{src}, eqs. 19 and 22, lines 1446, 1460-1467", _PRINTED_OFFSET["U1"]),
        "V1": Budget("V1", tuple(v1), "um", f"{src}, eqs. 20 and 23, lines 1448, 1469-1473", _PRINTED_OFFSET["V1"]),
        "W1": Budget("W1", tuple(w1), "um", w_src, _PRINTED_OFFSET["W1"]),
    }


def sphere_centre_budget(*, digitizer: float = 9.0, sphere_fit: float = 10.0) -> Budget:
    """Uncertainty of one compensated sphere centre (thesis section 6.2.3, line 1637).

    u_p^2 = 9^2 + 10^2: the digitizer's point accuracy and the sphere-centre fit.

    Parameters
    ----------
    digitizer : float
        Digitizer point accuracy, um (thesis: 9, Hymarc).
    sphere_fit : float
        Sphere-centre fit algorithm uncertainty, um (thesis: 10, Rosenfeld 1996).

    Returns
    -------
    Budget
        In um; u_c = 13.45 um, which the thesis prints (rounded up) as 14 um.
    """
    dig, fit = finite("digitizer", digitizer), finite("sphere_fit", sphere_fit)
    if min(dig, fit) < 0:
        raise InputError("digitizer, sphere_fit: uncertainties must be >= 0 (um)")
    printed = 14.0 if (dig, fit) == (9.0, 10.0) else None
    return Budget("sphere centre (compensated)", (
        Input("digitizer point accuracy", 0.0, dig, "um", 1.0, "Hymarc, 1 sigma (Table 17, line 1268)"),
        Input("sphere-centre fit", 0.0, fit, "um", 1.0, "NIST algorithm, 'Fit' column of Figure C-2 (Rosenfeld 1996)"),
    ), "um", "thesis section 6.2.3, line 1637", printed)


def ballbar_length_budget(n_positions: int = 1, compensated: bool = True, *, temperature: float = 20.0,
                          digitizer: float = 9.0, sphere_fit: float = 10.0, scale=None) -> Budget:
    """Uncertainty of a ballbar length, or of the mean of ``n_positions`` lengths.

    Compensated (section 6.2.3, line 1637): each of the two centres has
    u_p^2 = 9^2 + 10^2, so u_L^2 = 2 u_p^2 for one length. Uncompensated
    (section 6.4.1, lines 1751-1753): u^2 = 9^2 + 10^2 + s_X^2 + s_Y^2 + s_Z^2
    with the worst-case scale errors s at the temperature (the thesis counts the
    digitizer and fit terms once here, not per ball; reproduced as printed).
    The mean of n uncorrelated lengths divides by sqrt(n): every input gets the
    sensitivity 1/sqrt(n) (n repetitions of it, each with sensitivity 1/n).

    Parameters
    ----------
    n_positions : int
        Lengths averaged (1 for a single length; thesis 8 in section 6.2, 20 per
        temperature in 6.3 and 6.4).
    compensated : bool
        Compensated (6.2.3) or uncompensated (6.4.1) data.
    temperature : float
        Machine temperature, degrees C, choosing the scale errors of the
        uncompensated budget (20, 25 or 30; ignored when compensated or when
        ``scale`` is given).
    digitizer : float
        Digitizer point accuracy, um (thesis: 9).
    sphere_fit : float
        Sphere-centre fit uncertainty, um (thesis: 10).
    scale : sequence of 3 float, optional
        Scale errors of X, Y, Z over the length, um (uncompensated only);
        default ``THESIS_SCALE_ERRORS_UM[temperature]``.

    Returns
    -------
    Budget
        In um, with ``printed`` set where the thesis prints this figure.
    """
    if isinstance(n_positions, bool) or not isinstance(n_positions, (int, np.integer)) or n_positions < 1:
        raise InputError(f"n_positions: expected a positive integer, got {n_positions!r}")
    n = int(n_positions)
    dig, fit = finite("digitizer", digitizer), finite("sphere_fit", sphere_fit)
    if min(dig, fit) < 0:
        raise InputError("digitizer, sphere_fit: uncertainties must be >= 0 (um)")
    c = 1.0 / math.sqrt(n)
    mean = f"mean of {n} positions" if n > 1 else "single position"
    default = (dig, fit) == (9.0, 10.0)
    if compensated:
        inputs = tuple(
            Input(f"ball {b}: {what}", 0.0, u, "um", c, note)
            for b in (1, 2)
            for what, u, note in (("digitizer point accuracy", dig, "Hymarc (line 1637)"),
                                  ("sphere-centre fit", fit, "Rosenfeld 1996 (line 1637)"))
        )
        printed = _PRINTED_LENGTH.get((True, None, n)) if default else None
        return Budget(f"ballbar length, compensated, {mean}", inputs, "um", "thesis section 6.2.3, line 1637", printed)
    t = finite("temperature", temperature)
    if scale is None:
        if t not in THESIS_SCALE_ERRORS_UM:
            raise InputError(f"temperature: the thesis gives scale errors at 20, 25 and 30 C only, got {t}; pass scale=(sX, sY, sZ) in um")
        s, note = THESIS_SCALE_ERRORS_UM[t], f"worst case at {t:g} C (lines 1751-1753)"
        printed = _PRINTED_LENGTH.get((False, t, n)) if default else None
    else:
        s, note, printed = as_triple("scale", scale), "given", None
        if min(s) < 0:
            raise InputError("scale: uncertainties must be >= 0 (um)")
    inputs = (
        Input("digitizer point accuracy", 0.0, dig, "um", c, "along the bar only (line 1751)"),
        Input("sphere-centre fit", 0.0, fit, "um", c, "not split into axes (line 1753)"),
        *(Input(f"{a} scale error", 0.0, v, "um", c, note) for a, v in zip("XYZ", s)),
    )
    label = f"{t:g} C" if scale is None else "given scale errors"
    return Budget(f"ballbar length, uncompensated, {label}, {mean}", inputs, "um",
                  "thesis section 6.4.1, lines 1751-1753", printed)
