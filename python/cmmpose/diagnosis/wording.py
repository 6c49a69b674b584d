"""Words for numbers: a change said with the verb its sign calls for, and
advice never asking for a measurement the run already holds.

Every sentence the diagnosis prints or writes about a figure going up or
down is built here, so that "fell from 4.34 um to 4.35 um" cannot be said
(issue 33, section 7).
"""

from __future__ import annotations

import math

__all__ = ["change_text", "rms_u_um", "change_u_um", "held_measurements", "without_held_needs"]


def rms_u_um(rms_um: float | None, n: int | None) -> float | None:
    """Standard uncertainty of an rms figure taken over ``n`` values, um.

    An rms of ``n`` values scattered about their mean has a relative standard
    uncertainty of about 1 / sqrt(2 (n - 1)) (chi-square with n - 1 degrees
    of freedom).

    Parameters
    ----------
    rms_um : float or None
        The rms, um.
    n : int or None
        Number of values it was taken over.

    Returns
    -------
    float or None
        um; None when it cannot be said (no figure, fewer than two values).
    """
    if rms_um is None or n is None or n < 2 or not math.isfinite(rms_um):
        return None
    return abs(rms_um) / math.sqrt(2.0 * (n - 1))


def change_u_um(u_before: float | None, u_after: float | None) -> float | None:
    """Standard uncertainty of the change between two figures, um: their
    uncertainties added in quadrature (conservative: two figures of the same
    run are positively correlated, so the change is known better than this).
    None when either is unknown."""
    if u_before is None or u_after is None or not (math.isfinite(u_before) and math.isfinite(u_after)):
        return None
    return math.hypot(u_before, u_after)


def change_text(what: str, before_um: float, after_um: float, u_um: float | None = None) -> str:
    """``what`` going from ``before_um`` to ``after_um``, in words whose verb
    follows the sign of the change.

    Parameters
    ----------
    what : str
        The figure, e.g. 'the rms accuracy error'.
    before_um, after_um : float
        Its value before and after, um.
    u_um : float, optional
        Standard uncertainty of the change, um. A change within it is said
        to be unchanged (with the change and its uncertainty).

    Returns
    -------
    str
        'the rms accuracy error fell from 8.15 um to 0.24 um', '... rose
        from ...', '... stayed at 4.34 um' (equal as printed) or '... is
        unchanged within its uncertainty: 4.34 um, then 4.35 um (change
        +0.01 ± 0.70 um)'.
    """
    a, b = f"{before_um:.2f}", f"{after_um:.2f}"
    change = after_um - before_um
    if u_um is not None and math.isfinite(u_um) and abs(change) <= u_um:
        return (f"{what} is unchanged within its uncertainty: {a} um, then {b} um "
                f"(change {change:+.2f} ± {u_um:.2f} um)")
    if a == b:
        return f"{what} stayed at {a} um"
    return f"{what} {'fell' if change < 0 else 'rose'} from {a} um to {b} um"


def held_measurements(has: dict | None, reveal: str) -> list[str]:
    """The measurements named in ``reveal`` that the run already holds
    (``has``: measurement -> bool, :func:`cmmpose.diagnosis.diagnose.run_holds`)."""
    return [k for k, v in (has or {}).items() if v and k in reveal]


def without_held_needs(text: str, reveal: str, has: dict | None) -> str:
    """``text`` with its advice to take ``reveal`` ('needs: <reveal>')
    rewritten when the run already holds what ``reveal`` asks for: then the
    run has it and it still does not pin the effect.

    Parameters
    ----------
    text : str
        A reason or advice holding 'needs: <reveal>' (or nothing to change).
    reveal : str
        The measurement that would reveal the effect.
    has : dict of str -> bool or None
        What the run holds; None or empty: ``text`` as it is.
    """
    held = held_measurements(has, reveal)
    if not held or not reveal or reveal not in text:
        return text
    said = (f"the run already has this ({', '.join(held)}) and it still does not pin the effect (larger or more "
            f"varied positions, or a longer run, would)")
    return text.replace(f"needs: {reveal}", said).replace(reveal, said)
