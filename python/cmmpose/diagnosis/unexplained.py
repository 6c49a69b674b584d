"""Structure no library effect explains: what the final model's residuals
still hold, named by the input it follows, with its size and significance,
and a user-effect skeleton built on that input.

Two kinds of finding:

- **patterns**: the significant residual patterns of the final model
  (:func:`cmmpose.diagnosis.patterns.find_patterns`: lengths, scans and points
  against direction, position, u, v, incidence, time, temperature), each with
  the library effects that could make it and which of them the model already
  holds;
- **periodic errors along an axis** (a lead screw, a scale's graduation or
  interpolation error), or **local** ones where the sine found holds only on
  a stretch of the travel (:func:`local_extent`: a local defect is never
  called periodic): the point residuals regressed on
  n_axis (a sin(2 pi s / P) + b cos(2 pi s / P)), s the axis's scale reading
  and n_axis the outward sphere normal's component along it, for every period
  P from 2 mm to 40 mm at once (the sums are binned by s and taken with one
  FFT per axis). Longer periods barely change one ball's shape: they move
  whole balls, and the map-correction family searches them over the whole
  travel from the ball centres (:mod:`cmmpose.diagnosis.mapfamily`, 10 mm to
  the travel, period and amplitude with uncertainties). A reading varies
  within a scan only along the sweep, so a periodic error shows on the axes
  the run sweeps (all X for the B89 layout; X and Y for the crossed one); on
  another axis it moves whole scans, which the sphere fits take up. And the
  reading moves only from one profile to the next (5.3 mm at 35 mm/s and
  6.6 profiles/s): periods under 2.1 profile spacings are not searched, as
  they alias.

Significance. A periodic finding's F statistic (2 and N - 2 degrees of
freedom, the point residuals being independent scanner noise) must beat
``alpha`` divided by the number of independent periods tested on the three
axes (Bonferroni), and its amplitude must reach ``floor_um`` (0.2 um, twice
the diagnosis's SIGMA_FLOOR: smaller structure is within the model's own
approximations).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..run import Run
from .patterns import scan_sphere_fits, f_test_p_value

__all__ = ["Finding", "periodic_errors", "unexplained_findings", "user_effect_skeleton"]

#: Width of the reading bins the periodic sums are taken over, mm: the phase
#: moves by at most 2 pi h / (2 P_min) = 0.08 rad within one.
BIN_MM = 0.05
#: Periods searched, mm.
PERIODS_MM = (2.0, 40.0)
#: A scan counts as swept along an axis when its reading of that axis spans
#: this much, mm (a 38 mm ball swept over its diameter spans some 50 mm).
SWEPT_MM = 10.0
#: Smallest amplitude reported, um.
FLOOR_UM = 0.2
#: The scale reading of each machine axis, as the run names it.
_AXES = (("D", 0, "x"), ("E", 1, "y"), ("F", 2, "z"))

#: Point inputs a user effect receives for each pattern quantity (docs/diagnosis.md).
_INPUT_OF = {"u": "u", "v": "v", "incidence": "incidence", "D in scan": "D", "E in scan": "E", "F in scan": "F",
             "t in scan": "t", "temperature": "temperature", "mid x": "x", "mid y": "y", "mid z": "z",
             "time": "t", "pose": "pose_id", "position": "scan_id", "sweep direction": "scan_id",
             "sweep axis": "scan_id", "sweep speed": "scan_id"}
#: Library effects a pattern's quantity points to (to say which the model already holds).
_EFFECTS_OF = {"u": ("scanner-scale",), "v": ("scanner-scale",), "incidence": ("incidence",),
               "D in scan": ("roll",), "E in scan": ("roll",), "F in scan": ("roll",), "t in scan": ("latency",),
               "temperature": ("axis-temperature", "granite-gradient"), "dx*dy": ("squareness",),
               "dy*dz": ("squareness",), "dz*dx": ("squareness",), "dx^2": ("scale",), "dy^2": ("scale",),
               "dz^2": ("scale",), "sweep direction": ("latency",), "pose": ("alignment", "mount-offset")}


@dataclass(frozen=True)
class Finding:
    """Structure in the final model's residuals.

    Attributes
    ----------
    kind : {'periodic', 'local', 'pattern'}
        A periodic error along an axis, a local one (a sine fits it only
        where it sits, :func:`local_extent`), or a residual pattern.
    input : str
        The run input it follows ('D', 'E', 'F' scale readings in mm, 'u', 'v'
        in mm, 'incidence' in degrees, 't' in s, 'temperature' in C, 'x', 'y',
        'z' in mm, 'pose_id', 'scan_id').
    description : str
        One line in words.
    size_um : float
        Amplitude (periodic) or peak-to-peak of the fitted pattern, um.
    p_value : float
        Its significance (dimensionless).
    threshold : float
        The p-value it had to beat (Bonferroni), dimensionless.
    period_mm : float or None
        The period of a periodic finding, mm.
    phase : tuple of float or None
        (sin, cos) amplitudes of a periodic finding, um, with the phase taken
        from a reading of 0 mm.
    axis : str or None
        'x', 'y' or 'z' for a periodic finding.
    library : tuple of str
        Library effects that could make a pattern.
    in_model : tuple of str
        Those of ``library`` the model already holds (the library cannot
        explain the rest of it).
    """

    kind: str
    input: str
    description: str
    size_um: float
    p_value: float
    threshold: float
    period_mm: float | None = None
    phase: tuple | None = None
    axis: str | None = None
    library: tuple = ()
    in_model: tuple = ()
    #: Of a local finding: the reading range (from, to) where it sits, mm.
    where_mm: tuple | None = None

    def to_dict(self) -> dict:
        def num(v):
            return None if v is None or not math.isfinite(float(v)) else float(v)

        return {"kind": self.kind, "input": self.input, "description": self.description, "size_um": num(self.size_um),
                "p_value": num(self.p_value), "threshold": num(self.threshold), "period_mm": num(self.period_mm),
                "phase_um": None if self.phase is None else [num(v) for v in self.phase], "axis": self.axis,
                "library": list(self.library), "in_model": list(self.in_model),
                "where_mm": None if self.where_mm is None else [num(v) for v in self.where_mm]}


def periodic_errors(run: Run, xyz, fits, *, alpha: float = 1e-3, floor_um: float = FLOOR_UM) -> list[Finding]:
    """Periodic errors along each machine axis in the point residuals (see the module docstring).

    Parameters
    ----------
    run : Run
        The run (its scale readings D, E, F in mm).
    xyz : ndarray (N, 3)
        Compensated coordinates of the run's points, mm.
    fits : mapping of scan id -> SphereFit
        ``fit_spheres(xyz, run.points['scan_id'])``.
    alpha : float
        Family-wise significance level, dimensionless.
    floor_um : float
        Smallest amplitude reported, um.

    Returns
    -------
    list of Finding
        The significant periodic error of each axis that has one, largest first.
    """
    ids, counts, centres, _, _, residual, inlier = scan_sphere_fits(run, fits)
    keep = inlier
    if keep.sum() < 100:
        return []
    scan_index = np.searchsorted(ids, run.points["scan_id"])[keep]
    normal = np.asarray(xyz, dtype=float)[keep] - centres[scan_index]
    normal /= np.maximum(np.linalg.norm(normal, axis=1), 1e-300)[:, None]
    r_all = residual[keep] * 1e3  # um
    results = []
    tested = 0
    for reading, j, axis in _AXES:
        s_all = np.asarray(run.points[reading], dtype=float)[keep]
        # Only scans swept along the axis: elsewhere the reading stays put
        # during the scan and the sphere fit takes up whatever error it has.
        lo_s = np.full(len(ids), np.inf)
        hi_s = np.full(len(ids), -np.inf)
        np.minimum.at(lo_s, scan_index, s_all)
        np.maximum.at(hi_s, scan_index, s_all)
        swept = (hi_s - lo_s >= SWEPT_MM)[scan_index]
        if swept.sum() < 100:
            continue
        s, nj, r = s_all[swept], normal[swept, j], r_all[swept]
        n = len(r)
        rss0 = float(r @ r)
        lo, hi = float(s.min()), float(s.max())
        # The reading moves only from one profile to the next: periods under
        # two profile spacings alias (Nyquist), so the search starts above them.
        key = np.lexsort((s, scan_index[swept]))
        step = np.diff(s[key])[np.diff(scan_index[swept][key]) == 0]
        step = step[step > 1e-9]
        p_min = max(PERIODS_MM[0], 2.1 * float(np.median(step))) if len(step) else PERIODS_MM[0]
        if p_min >= PERIODS_MM[1]:
            continue
        span = hi - lo
        if span < 2 * PERIODS_MM[0]:
            continue
        k = np.floor((s - lo) / BIN_MM).astype(np.int64)
        m_size = 1 << int(math.ceil(math.log2(2 * (int(k.max()) + 1))))  # zero-padded twice: fine period steps
        b_rn = np.bincount(k, weights=r * nj, minlength=m_size)
        b_nn = np.bincount(k, weights=nj * nj, minlength=m_size)
        f_rn = np.fft.rfft(b_rn)
        f_nn = np.fft.rfft(b_nn)
        # period P = m_size * BIN_MM / m
        m_lo = max(1, int(math.floor(m_size * BIN_MM / PERIODS_MM[1])))
        m_hi = min(int(math.ceil(m_size * BIN_MM / p_min)), (len(f_nn) - 1) // 2)
        m = np.arange(m_lo, m_hi + 1)
        c_rn, s_rn = f_rn[m].real, -f_rn[m].imag
        c2, s2 = f_nn[2 * m].real, -f_nn[2 * m].imag
        total = float(b_nn.sum())
        ss, cc, sc = (total - c2) / 2, (total + c2) / 2, s2 / 2
        det = ss * cc - sc * sc
        ok = det > 1e-12 * total * total
        a = np.where(ok, (cc * s_rn - sc * c_rn) / np.where(ok, det, 1.0), 0.0)
        b = np.where(ok, (ss * c_rn - sc * s_rn) / np.where(ok, det, 1.0), 0.0)
        gain = a * s_rn + b * c_rn
        # Independent periods: the frequency spacing 1/span over the band (zero padding adds none).
        tested += max(1, int(round((1 / p_min - 1 / PERIODS_MM[1]) * span)))
        best = int(np.argmax(gain))
        # Refine the period between the neighbouring FFT frequencies on the
        # binned sums (bin centres), so the phase holds over the whole travel.
        centre_s = lo + (np.arange(m_size) + 0.5) * BIN_MM
        used = b_nn > 0
        cs, b_rn_u, b_nn_u = centre_s[used], b_rn[used], b_nn[used]
        freqs = np.linspace(max(m[best] - 1, 0.5), m[best] + 1, 81) / (m_size * BIN_MM)
        ph = 2 * np.pi * np.outer(freqs, cs)
        sn, cn = np.sin(ph), np.cos(ph)
        S, C = sn @ b_rn_u, cn @ b_rn_u
        SS, CC, SC = (sn * sn) @ b_nn_u, (cn * cn) @ b_nn_u, (sn * cn) @ b_nn_u
        det_f = SS * CC - SC * SC
        af = (CC * S - SC * C) / det_f
        bf = (SS * C - SC * S) / det_f
        gf = af * S + bf * C
        i = int(np.argmax(gf))
        f = (gf[i] / 2) / max((rss0 - gf[i]) / (n - 2), 1e-300)
        amp = float(math.hypot(af[i], bf[i]))
        period = 1.0 / float(freqs[i])
        # phases are taken from a reading of 0 mm (bin centres are absolute readings)
        sin_amp, cos_amp = float(af[i]), float(bf[i])
        sigma = math.sqrt(max((rss0 - gf[i]) / (n - 2), 1e-300))
        where = local_extent(s, nj, r, period, (sin_amp, cos_amp), sigma)
        results.append((axis, reading, period, amp, f_test_p_value(float(f), 2, n - 2), (sin_amp, cos_amp), where))
    threshold = alpha / max(tested, 1)
    out = []
    for axis, reading, period, amp, p, phase, where in sorted(results, key=lambda t: -t[3]):
        if p < threshold and amp >= floor_um:
            if where is None:
                out.append(Finding("periodic", reading, f"a periodic error along {axis} following the {reading} "
                                   f"scale reading: {amp:.2f} um amplitude, period {period:.2f} mm (a lead screw, a "
                                   f"scale's graduation or interpolation error); no library effect is periodic", amp,
                                   p, threshold, period_mm=period, phase=phase, axis=axis))
                continue
            a, b, size = where
            out.append(Finding("local", reading, f"a local error along {axis} following the {reading} scale reading "
                               f"near {reading} = {a:.0f}-{b:.0f} mm: {size:.2f} um there (a sine of period "
                               f"{period:.2f} mm fits it there but not over the swept travel, so it is not periodic: "
                               f"a local scale or guideway defect); no library effect is local", size, p, threshold,
                               period_mm=period, phase=phase, axis=axis, where_mm=(a, b)))
    return out


#: Segments of the swept travel a periodic finding is checked in (at most), and the fewest points in one.
SEGMENTS, SEGMENT_POINTS = 8, 200
#: A stretch of the travel that a local finding may hold at most: this share of the sine's weight.
LOCAL_SHARE = 0.5


def local_extent(s, nj, r, period, phase, sigma):
    """Whether the sine a periodic search found holds over the swept travel,
    or only on a stretch of it: a local error, which a sine fits there.

    The travel [min s, max s] is cut into up to :data:`SEGMENTS` segments
    (each at least three periods and 40 mm long; those with fewer than
    :data:`SEGMENT_POINTS` points left out). The sine at the found period
    and phase is fitted with a free amplitude over the whole travel and over
    each stretch of consecutive segments holding at most :data:`LOCAL_SHARE`
    of its weight. The error is local when the best stretch explains more
    of the residuals than the whole travel does, by more than the choice of
    the stretch buys by chance (2 ln of the number of stretches tried, plus
    2, in units of the residuals' variance): a local defect fitted over the
    whole travel is diluted, a periodic error confined to a stretch loses
    the rest of it.

    Parameters
    ----------
    s, nj, r : ndarray (N,)
        The scale reading (mm), the outward normal's component along its
        axis, and the point residuals (um).
    period : float
        mm.
    phase : tuple of float
        (sin, cos) amplitudes, um.
    sigma : float
        The residuals' scatter about the sine, um.

    Returns
    -------
    tuple of float or None
        (from, to) reading in mm of the stretch where it sits and its
        amplitude there (um); None when it holds over the travel (or fewer
        than three segments hold enough points to say).
    """
    lo, hi = float(np.min(s)), float(np.max(s))
    k = int(min(SEGMENTS, (hi - lo) // max(3 * period, 40.0)))
    if k < 3:
        return None
    g = nj * (phase[0] * np.sin(2 * np.pi * s / period) + phase[1] * np.cos(2 * np.pi * s / period))
    edges = np.linspace(lo, hi, k + 1)
    seg = np.clip(np.searchsorted(edges, s, side="right") - 1, 0, k - 1)
    gg = np.bincount(seg, g * g, minlength=k)
    rg = np.bincount(seg, r * g, minlength=k)
    count = np.bincount(seg, minlength=k)
    use = np.flatnonzero((count >= SEGMENT_POINTS) & (gg > 0))
    if len(use) < 3:
        return None
    total_gg = float(gg[use].sum())
    whole = float(rg[use].sum()) ** 2 / total_gg
    best, tried = None, 0
    for i in range(len(use)):
        for j in range(i, len(use)):
            w = use[i:j + 1]
            wgg = float(gg[w].sum())
            if wgg > LOCAL_SHARE * total_gg:
                break
            tried += 1
            explained = float(rg[w].sum()) ** 2 / wgg
            if best is None or explained > best[0]:
                best = (explained, int(w[0]), int(w[-1]), float(rg[w].sum()) / wgg)
    if best is None or (best[0] - whole) / sigma ** 2 <= 2 * math.log(max(tried, 1)) + 2:
        return None
    _, a, b, factor = best
    return float(edges[a]), float(edges[b + 1]), abs(factor) * math.hypot(*phase)


def unexplained_findings(patterns, periodic: list[Finding], model_names) -> list[Finding]:
    """The findings of a diagnosis: the periodic errors, then each significant
    pattern of the final model with the library effects it points to and
    those the model already holds.

    Parameters
    ----------
    patterns : Patterns or None
        The final model's residual patterns.
    periodic : list of Finding
        From :func:`periodic_errors`.
    model_names : sequence of str
        Effects in the final model.
    """
    out = list(periodic)
    if patterns is None:
        return out
    names = set(model_names)
    for p in patterns:
        if not p.significant:
            continue
        lib = _EFFECTS_OF.get(p.quantity, ())
        held = tuple(e for e in lib if e in names)
        if lib and len(held) == len(lib):
            why = f"the effects that would make it ({', '.join(lib)}) are in the model already"
        elif lib:
            why = f"consistent with {p.hint}"
        else:
            why = f"consistent with {p.hint}; no library effect follows {p.quantity}"
        out.append(Finding("pattern", _INPUT_OF.get(p.quantity, p.quantity),
                           f"{p.title} ({p.model}): {p.amplitude_um:.2f} um, R^2 {p.r2:.2f}; {why}",
                           float(p.amplitude_um), float(p.p_value), float(patterns.threshold), library=lib,
                           in_model=held))
    return out


def user_effect_skeleton(finding: Finding, name: str = "my-effect") -> str:
    """The text of a Python file that defines a user effect on ``finding``'s input.

    The file defines ``EFFECT`` (a :class:`cmmpose.UserEffect`),
    which ``cmmpose diagnose RUN --user-effect FILE`` adds to the candidates.
    A periodic finding gets a sine and a cosine at its period along its axis;
    a local one a bump where it sits; any other a correction linear in its input along x, y and z, to be edited
    into the physics suspected.
    """
    head = (f'"""User effect drafted by cmmpose diagnose from the finding:\n\n    {finding.description}\n\n'
            'Edit the correction into the physics you suspect: it returns an (N, 3) correction in mm, added to\n'
            'the compensated coordinates, and must be zero when every parameter is zero. Then:\n\n'
            '    cmmpose diagnose RUN --user-effect THIS_FILE.py\n"""\n\n'
            "import numpy as np\n\nfrom cmmpose import UserEffect\n\n")
    if finding.kind == "periodic":
        j = "xyz".index(finding.axis)
        return head + (
            f"PERIOD_MM = {finding.period_mm:.4g}  # from the finding; a lead screw's pitch, a scale's period\n\n\n"
            f"def correction(inputs, sin_um, cos_um):\n"
            f"    phase = 2 * np.pi * inputs[{finding.input!r}] / PERIOD_MM\n"
            f"    out = np.zeros((len(phase), 3))\n"
            f"    out[:, {j}] = -(sin_um * np.sin(phase) + cos_um * np.cos(phase)) * 1e-3  # um -> mm\n"
            f"    return out\n\n\n"
            f"EFFECT = UserEffect.create(\n"
            f"    {name!r}, correction, {{'sin_um': ('um', 1.0), 'cos_um': ('um', 1.0)}},\n"
            f"    physics='a periodic error along {finding.axis} with the {finding.input} reading',\n"
            f"    reveal='scans spread along {finding.axis} over several periods')\n")
    if finding.kind == "local" and finding.where_mm is not None:
        j = "xyz".index(finding.axis)
        a, b = finding.where_mm
        return head + (
            f"CENTRE_MM, HALF_WIDTH_MM = {(a + b) / 2:.4g}, {(b - a) / 2:.4g}  # where the finding sits\n\n\n"
            f"def correction(inputs, bump_um):\n"
            f"    s = (np.asarray(inputs[{finding.input!r}], dtype=float) - CENTRE_MM) / HALF_WIDTH_MM\n"
            f"    out = np.zeros((len(s), 3))\n"
            f"    out[:, {j}] = -bump_um * np.exp(-s * s) * 1e-3  # um -> mm; edit the shape to the physics\n"
            f"    return out\n\n\n"
            f"EFFECT = UserEffect.create(\n"
            f"    {name!r}, correction, {{'bump_um': ('um', 1.0)}},\n"
            f"    physics='a local error along {finding.axis} near {finding.input} = {a:.0f}-{b:.0f} mm',\n"
            f"    reveal='scans spread along {finding.axis} over and beside that stretch')\n")
    code, unit = _quantity_code(finding.input)
    return head + (
        f"def correction(inputs, gx, gy, gz):\n"
        f"    {code}  # {finding.input}, {unit}\n"
        f"    s = s - s.mean()\n"
        f"    return np.column_stack([gx * s, gy * s, gz * s]) * 1e-3  # um per {unit} -> mm\n\n\n"
        f"EFFECT = UserEffect.create(\n"
        f"    {name!r}, correction, {{'gx': ('um/{unit}', 1.0), 'gy': ('um/{unit}', 1.0), 'gz': ('um/{unit}', 1.0)}},\n"
        f"    physics='an error linear in {finding.input} (edit me)', reveal='scans that vary {finding.input}')\n")


def _quantity_code(quantity: str) -> tuple[str, str]:
    """One line of Python that sets ``s`` (N,) to ``quantity`` from a user
    effect's inputs (USER_INPUTS), and its unit: every quantity of the
    pattern vocabulary (:mod:`cmmpose.diagnosis.patterns`) has one, so a
    drafted skeleton runs as written. A quantity the inputs do not carry
    (a ballbar's direction cosines, a categorical scan property) is
    approximated from what they do carry, and the line says so."""
    direct = {"u": "mm", "v": "mm", "D": "mm", "E": "mm", "F": "mm", "x": "mm", "y": "mm", "z": "mm",
              "incidence": "degree", "t": "s", "temperature": "C", "scan_id": "1", "pose_id": "1"}
    q = quantity.strip()
    if q in direct:
        return f"s = np.asarray(inputs[{q!r}], dtype=float)", direct[q]
    if q.startswith("mid ") and q[4:] in ("x", "y", "z"):
        return f"s = np.asarray(inputs[{q[4:]!r}], dtype=float)  # the point's position stands for the bar's mid-point", "mm"
    if q.endswith(" in scan") and q[:-8] in ("D", "E", "F", "t"):
        k = q[:-8]
        return (f"_r = np.asarray(inputs[{k!r}], dtype=float); _, _i = np.unique(inputs['scan_id'], "
                f"return_inverse=True); s = _r - (np.bincount(_i, _r) / np.bincount(_i))[_i]"), \
            ("s" if k == "t" else "mm")
    cos = {"dx": "_d[:, 0]", "dy": "_d[:, 1]", "dz": "_d[:, 2]"}
    expr = q.replace("^2", "**2")
    names = expr.replace("*", " ").split()
    if names and all(n in cos or n == "2" for n in names):
        for k, v in cos.items():
            expr = expr.replace(k, v)
        return ("_p = np.column_stack([inputs['x'], inputs['y'], inputs['z']]); _p = _p - _p.mean(axis=0); "
                "_d = _p / np.maximum(np.linalg.norm(_p, axis=1), 1e-9)[:, None]; "
                f"s = {expr}  # direction cosines of the point from the run's centroid stand for the bar's"), "1"
    return (f"s = np.asarray(inputs['scan_id'], dtype=float)  # {q!r} is not a user-effect input: "
            f"the scan id stands for it (edit me)"), "1"
