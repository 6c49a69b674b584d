"""A run's temperatures under a :class:`~cmmpose.temperature.TemperaturePolicy`:
:func:`run_temperatures` (the machine temperature) and
:func:`run_sensor_temperatures` (every temperature the diagnosis reads), with
the provenance (channels dropped and why, points held and how long, the
channels each role read: :func:`log_provenance`, :func:`log_notes`).

Units: times in s, temperatures in degrees C, temperature differences in K.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .._lazy import LazyModule
from ..errors import InputError, InputTypeError
from .interpolation import AXIS_ROLES, ThermalSummary, temperatures_at
from .log import LogReport, check_log, check_log_coverage
from .policy import DEFAULT_POLICY, LOG_HOLD, TemperaturePolicy, as_policy

# The run format loads on first use (tests/compensation/test_pipeline_and_import_footprint.py).
_run = LazyModule("cmmpose.run")

if TYPE_CHECKING:
    from ..run import Run

__all__ = ["run_temperatures", "run_sensor_temperatures", "SensorTemperatures", "log_provenance", "log_notes",
           "GRADIENT_WINDOW"]

#: Width of the running mean of a sensor's departure from the machine mean, s.
GRADIENT_WINDOW = 300.0
#: Why a channel was dropped, by problem kind (for the provenance).
_WHY = {"stuck": "constant (stuck while the others vary)", "open_circuit": "open circuit (a burn-out reading)",
        "implausible": "out of the plausible range", "nan": "NaN or infinite"}


# -- a run's temperatures under a policy --------------------------------------------
def _policy_channels(channels, policy: TemperaturePolicy) -> tuple[list[dict], dict[str, dict]]:
    """The run's channels with the roles the policy's ``sensors`` give them,
    and for each channel whose role changed: its role in the log and the one read."""
    out = [{"name": c.get("name"), "role": c.get("role")} for c in channels]
    names = [c["name"] for c in out]
    moved: dict[str, dict] = {}
    for role, chosen in policy.sensors:
        missing = [n for n in chosen if n not in names]
        if missing:
            raise InputError(f"sensors: role {role!r} names channel {missing[0]!r}, not in the log "
                             f"(channels: {', '.join(names)})")
        for c in out:
            if c["name"] in chosen and c["role"] != role:
                moved.setdefault(c["name"], {"log_role": c["role"]})["read_as"] = role
                c["role"] = role
            elif c["role"] == role and c["name"] not in chosen:
                moved.setdefault(c["name"], {"log_role": role})["read_as"] = None
                c["role"] = None
    return [c for c in out if c["role"] is not None], moved


def _check_broken(rep: LogReport, channels: list[dict], roles, policy: TemperaturePolicy) -> None:
    if policy.broken_channels != "raise":
        return
    read = [c["name"] for c in channels if c["role"] in roles]
    bad = [p for p in rep.problems if p.channel in read and p.kind != "gap"]
    if bad:
        name = bad[0].channel
        raise InputError(f"thermocouple {name}: broken ({'; '.join(str(p) for p in bad if p.channel == name)})",
                         option="broken_channels", remedy="broken_channels")


def _log_of(run: Run, policy: TemperaturePolicy, t) -> tuple[list[dict], dict, LogReport]:
    if not isinstance(run, _run.Run):
        raise InputTypeError(f"run: expected a cmmpose.Run, got {type(run).__name__}")
    if run.temperatures is None:
        raise InputError("run has no temperature log", option="temperature", remedy="temperature_explicit")
    check_log_coverage(run, t, policy.log_hold)
    channels, moved = _policy_channels(run.temperature_channels, policy)
    rep = check_log(run.temperatures, channels, max_gap=policy.max_gap)
    return channels, moved, rep


def run_temperatures(run: Run, t, temperature_policy: TemperaturePolicy | None = None, *,
                     log_hold: float | None = None) -> tuple[np.ndarray, dict]:
    """The machine temperature of a run at times ``t`` (the mean of the clean
    axis-scale thermocouples, thesis 6.4) under a policy, and its provenance.

    Parameters
    ----------
    run : Run
        A run with a thermocouple log.
    t : array_like
        Times, s (``run.points['t']``).
    temperature_policy : TemperaturePolicy, optional
        Default :data:`DEFAULT_POLICY`.
    log_hold : float, optional
        s: overrides the policy's ``log_hold``.

    Returns
    -------
    temperatures : ndarray
        Degrees C, the shape of ``t``.
    log : dict
        JSON-ready provenance (:func:`log_provenance`): channels used, each
        channel dropped (role, why, how many samples, what was done), the
        points held past the log's ends and for how many seconds, the
        channels each axis role read, points interpolated across gaps and
        the log side of the policy.

    Raises
    ------
    InputError
        No log, a point beyond ``log_hold``, a gap (``on_gap='raise'``), a
        broken channel (``broken_channels='raise'``), a sensor naming a
        channel the log lacks.
    """
    policy = as_policy(temperature_policy, log_hold=log_hold)
    t = np.asarray(t, dtype=float)
    channels, moved, rep = _log_of(run, policy, t)
    _check_broken(rep, channels, AXIS_ROLES, policy)
    # Points of a profile share a time stamp: interpolate the log once per time.
    ut, inv = np.unique(t, return_inverse=True)
    temps, summary = temperatures_at(ut, run.temperatures, channels, policy="machine_mean", report=rep,
                                     on_gap=policy.on_gap, out_of_range="hold")
    log_t = np.asarray(run.temperatures["t"], float)
    prov = log_provenance({"the machine temperature": summary}, t, log_t, policy=policy, channels=channels,
                          moved=moved, roles=AXIS_ROLES)
    return temps[inv].reshape(np.shape(t)), prov


@dataclass(frozen=True, eq=False)
class SensorTemperatures:
    """A run's temperatures as the diagnosis reads them, from
    :func:`run_sensor_temperatures`.

    Attributes
    ----------
    temperature : ndarray (N,)
        Machine mean at each time, C.
    axis_temperature : ndarray (N, 3) or None
        Mean of each axis's scale channels, C (None without all three roles).
    gradient : ndarray (N,) or None
        Granite top minus bottom, K, running mean over ``GRADIENT_WINDOW``.
    sensors : dict of str -> ndarray (N,)
        Each role of the log -> the machine mean plus the role's departure
        from it (running mean over ``GRADIENT_WINDOW``), C.
    provenance : dict
        As :func:`run_temperatures`'s, over every role read, plus
        ``roles_left_out`` (role -> why).
    """

    temperature: np.ndarray
    axis_temperature: np.ndarray | None
    gradient: np.ndarray | None
    sensors: dict
    provenance: dict


def _running_mean(t: np.ndarray, y: np.ndarray, window: float) -> np.ndarray:
    """Mean of y over [t - window/2, t + window/2] at every t (sorted t)."""
    c = np.concatenate([[0.0], np.cumsum(y)])
    lo = np.searchsorted(t, t - window / 2, side="left")
    hi = np.searchsorted(t, t + window / 2, side="right")
    return (c[hi] - c[lo]) / (hi - lo)


def run_sensor_temperatures(run: Run, t, temperature_policy: TemperaturePolicy | None = None) -> SensorTemperatures:
    """Every temperature the diagnosis reads of a run at times ``t``: the
    machine mean, each axis's scale temperature, the granite gradient and
    each thermocouple role, under a policy, with the provenance.

    A role whose channels are all broken (or that the policy cannot read
    where needed) is left out and named in ``provenance['roles_left_out']``;
    the machine mean must be readable.

    Parameters
    ----------
    run : Run
        A run with a thermocouple log.
    t : array_like, shape (N,)
        Times, s.
    temperature_policy : TemperaturePolicy, optional
        Default :data:`DEFAULT_POLICY`.
    """
    policy = as_policy(temperature_policy)
    t = np.asarray(t, dtype=float)
    channels, moved, rep = _log_of(run, policy, t)
    roles = tuple(dict.fromkeys(c["role"] for c in channels if c["role"]))
    _check_broken(rep, channels, roles, policy)
    log = run.temperatures
    ut, inv = np.unique(t, return_inverse=True)
    kw = {"report": rep, "on_gap": policy.on_gap, "out_of_range": "hold"}
    temps, machine = temperatures_at(ut, log, channels, policy="machine_mean", **kw)
    summaries = {"the machine temperature": machine}
    temps = temps[inv]
    axis_t = gradient = None
    if all(r in roles for r in AXIS_ROLES):
        axis_t = temperatures_at(ut, log, channels, policy="per_axis", **kw)[0][inv]
    tlog = np.asarray(log["t"], dtype=float)
    mean_log = temperatures_at(tlog, log, channels, policy="machine_mean", **kw)[0]
    logs: dict[str, np.ndarray] = {}
    sensors: dict[str, np.ndarray] = {}
    left_out: dict[str, str] = {}
    for role in roles:
        try:
            role_log, summaries[f"role {role}"] = temperatures_at(tlog, log, channels, policy=f"role:{role}", **kw)
        except InputError as e:  # every channel of the role broken: the role is not offered
            left_out[role] = str(e)
            continue
        logs[role] = role_log
        # A sensor's departure from the mean changes over minutes; its
        # per-sample noise (0.02 K) would otherwise move each profile
        # on its own and masquerade as sphere-form structure.
        departure = _running_mean(tlog, role_log - mean_log, GRADIENT_WINDOW)
        sensors[role] = np.ascontiguousarray(temps + np.interp(ut, tlog, departure)[inv], dtype=float)
    if "granite_top" in logs and "granite_bottom" in logs:
        # The granite's gradient changes over hours, so the noise of the two
        # groups is averaged out over GRADIENT_WINDOW first (0.02 K of noise
        # times 15 arc-second/K is 1 um at 0.7 m).
        g = _running_mean(tlog, logs["granite_top"] - logs["granite_bottom"], GRADIENT_WINDOW)
        gradient = np.interp(ut, tlog, g)[inv]
    prov = log_provenance(summaries, t, tlog, policy=policy, channels=channels, moved=moved, roles=roles)
    prov["roles_left_out"] = left_out
    return SensorTemperatures(temps, axis_t, gradient, sensors, prov)


def log_provenance(summaries, t, log_t, *, policy: TemperaturePolicy | None = None, channels=None,
                   moved: dict | None = None, roles=AXIS_ROLES) -> dict:
    """The provenance of temperatures taken from a thermocouple log.

    Parameters
    ----------
    summaries : ThermalSummary or dict of str -> ThermalSummary
        From :func:`temperatures_at`, by what each gave (``'the machine
        temperature'``, ``'role mount'``); one summary is the machine
        temperature's.
    t : ndarray
        The points' time stamps, s.
    log_t : ndarray
        The log's sample times, s.
    policy : TemperaturePolicy, optional
        The policy used (its log side is recorded).
    channels : list of dict, optional
        The channels with the roles read (default the summaries' report's).
    moved : dict, optional
        Channels whose role the policy changed (channel -> ``log_role``, ``read_as``).
    roles : sequence of str
        The roles whose channels are listed in ``sensors``.

    Returns
    -------
    dict
        ``channels_used``; ``channels_dropped``: each channel with unclean
        samples (``channel``, ``role``, ``why`` (constant, open circuit,
        out of the plausible range, NaN), ``samples_dropped`` of
        ``samples``, ``problems``, ``action``); ``held``: the points outside
        the log (``points``, ``before_log_s``, ``after_log_s``, ``max_s``,
        ``log_hold_s``, ``action``) or None; ``points_across_gaps``;
        ``sensors``: role -> ``read`` (channels that gave a reading) and
        ``left_out`` (channels of the role that gave none); ``moved``;
        ``policy`` (the log side of the policy).
    """
    if isinstance(summaries, ThermalSummary):
        summaries = {"the machine temperature": summaries}
    policy = DEFAULT_POLICY if policy is None else policy
    first = next(iter(summaries.values()))
    report = first.report
    role_of = dict(zip(report.channels, report.roles)) if channels is None else \
        {c["name"]: c["role"] for c in channels}
    dropped, seen = [], set()
    used: list[str] = []
    for what, summary in summaries.items():
        used += [c for c in summary.channels_used if c not in used]
        for channel in summary.channels:
            n = int(summary.dropped_by_channel.get(channel, 0))
            entirely = channel in summary.channels_excluded
            if channel in seen or (not n and not entirely):
                continue
            seen.add(channel)
            problems = report.problems_of(channel)
            dropped.append({
                "channel": channel, "role": role_of.get(channel),
                "why": sorted({_WHY[p.kind] for p in problems if p.kind in _WHY}),
                "samples_dropped": n, "samples": int(report.samples),
                "problems": [str(p) for p in problems],
                "action": (f"left out of {what} entirely" if entirely else
                           f"left out where unclean ({n} of {report.samples} samples); the other channels "
                           "averaged there"),
            })
    held = None
    t = np.asarray(t, dtype=float).ravel()
    if len(t) and len(log_t):
        before, after = t < log_t.min(), t > log_t.max()
        if before.any() or after.any():
            b = round(float(log_t.min() - t.min()), 3) if before.any() else 0.0
            a = round(float(t.max() - log_t.max()), 3) if after.any() else 0.0
            held = {"points": int(before.sum() + after.sum()), "before_log_s": b, "after_log_s": a,
                    "max_s": max(a, b), "log_hold_s": policy.log_hold,
                    "action": "held at the log's first or last reading"}
    sensors = {}
    for role in roles:
        names = [n for n, r in role_of.items() if r == role]
        if names:
            sensors[role] = {"read": [n for n in names if n in used],
                             "left_out": [n for n in names if n not in used]}
    return {"channels_used": used, "channels_dropped": dropped, "held": held,
            "points_across_gaps": int(first.points_across_gaps),
            "sensors": sensors, "moved": dict(moved or {}), "policy": policy.log_dict()}


def log_notes(log: dict) -> list[str]:
    """One line per dropped channel, for held points, for points interpolated
    across gaps and for the channels each role read (when a channel was
    dropped or the policy chose them), for a printed result's notes."""
    notes = [f"thermocouple {d['channel']}{' (' + d['role'] + ')' if d.get('role') else ''}: {d['action']} "
             f"({'; '.join(d['problems']) or 'unclean samples'})"
             for d in log.get("channels_dropped", [])]
    held = log.get("held")
    if held:
        span = " and ".join(f"{held[k]:g} s {side}" for k, side in (("before_log_s", "before its first sample"),
                                                                    ("after_log_s", "after its last sample"))
                            if held[k])
        notes.append(f"the temperature log does not cover {held['points']} points (up to {span}): "
                     f"they took its nearest reading (held; at most {held.get('log_hold_s', LOG_HOLD):g} s allowed)")
    if log.get("points_across_gaps"):
        notes.append(f"{log['points_across_gaps']} points took temperatures interpolated across gaps of the "
                     "temperature log")
    for name, m in log.get("moved", {}).items():
        notes.append(f"thermocouple {name}: logged as {m['log_role']}, "
                     + (f"read as {m['read_as']}" if m["read_as"] else "not read") + " (the policy's sensors)")
    if log.get("channels_dropped") or log.get("moved"):
        read = "; ".join(f"{role} {', '.join(s['read']) or 'none'}" for role, s in log.get("sensors", {}).items())
        if read:
            notes.append(f"thermocouples read: {read}")
    for role, why in log.get("roles_left_out", {}).items():
        notes.append(f"thermocouple role {role}: left out ({why})")
    return notes
