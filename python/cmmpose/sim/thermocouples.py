"""A simulated thermocouple log: 11 channels as on the thesis machine (three
on each axis scale, granite top and bottom; section 6.4), sampled at a fixed
rate with noise, slow drift and optional faults."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..machine import CHANNELS  # noqa: F401  (the thesis machine's channels, simulated here)
from .machine import Temperature


#: What an open-circuit channel reads (degrees C): far outside any room, as
#: a data logger's burn-out detection reports it.
OPEN_CIRCUIT_READING = 999.9


@dataclass(frozen=True)
class Fault:
    """A channel that fails at ``at`` seconds: ``kind`` 'stuck' (holds its last
    reading) or 'open' (reads ``OPEN_CIRCUIT_READING``)."""

    channel: str
    kind: str
    at: float = 0.0

    def __post_init__(self):
        if self.channel not in dict(CHANNELS):
            raise InputError(f"fault channel {self.channel!r}: not one of {[c for c, _ in CHANNELS]}")
        if self.kind not in ("stuck", "open"):
            raise InputError(f"fault kind {self.kind!r}: expected 'stuck' or 'open'")


def thermocouple_log(
    duration: float,
    temperature: Temperature,
    *,
    rate: float = 1.0,
    axis_offsets=(0.0, 0.0, 0.0),
    granite_gradient: float = 0.0,
    role_offsets=None,
    extra_channels: tuple = (),
    noise: float = 0.02,
    drift: float = 0.0,
    faults: tuple[Fault, ...] = (),
    t0: float = 0.0,
    rng: np.random.Generator | int | None = None,
) -> dict[str, np.ndarray]:
    """Log of the 11 thermocouples over ``duration`` seconds.

    Parameters
    ----------
    duration : float
        Length of the log, s (> 0).
    temperature : float or callable
        Machine mean temperature, degrees C, or a function of time (s).
    rate : float
        Samples per second, Hz.
    axis_offsets : sequence of 3 float
        How much each axis's scale channels read above the mean, K.
    granite_gradient : float or callable
        Granite top minus bottom, K (split evenly around the mean), or a
        function of time (s) giving it.
    role_offsets : callable, optional
        ``role_offsets(t) -> {role: K}``: how far each role's channels read
        above the mean at times ``t`` (s), as the truth machine's effects say
        (``TruthMachine.role_offsets``); replaces ``axis_offsets`` and
        ``granite_gradient``.
    extra_channels : sequence of (str, str)
        Channels (name, role) logged after the 11 standard ones, e.g. the
        ones an effect brings (a 'mount' thermocouple).
    noise : float
        Gaussian noise per sample, K.
    drift : float
        Slow calibration drift of each channel, K per hour (a random sign per channel).
    faults : tuple of Fault
        Channels that fail during the log.
    t0 : float
        Time of the first sample, s.
    rng : Generator or int, optional
        Noise source.

    Returns
    -------
    dict
        ``t`` (s) and one array per channel name (degrees C).
    """
    if not (duration > 0 and rate > 0):
        raise InputError("duration and rate must be positive (s, Hz)")
    rng = np.random.default_rng(rng)
    t = t0 + np.arange(int(np.floor(duration * rate)) + 1) / rate
    mean = temperature(t) if callable(temperature) else np.full(t.shape, float(temperature))
    gradient = granite_gradient(t) if callable(granite_gradient) else float(granite_gradient)
    offsets = {"x_scale": axis_offsets[0], "y_scale": axis_offsets[1], "z_scale": axis_offsets[2],
               "granite_top": gradient / 2, "granite_bottom": -gradient / 2}
    if role_offsets is not None:
        offsets = {role: 0.0 for role in offsets} | dict(role_offsets(t))
    channels = (*CHANNELS, *extra_channels)
    signs = rng.choice([-1.0, 1.0], len(channels))
    log = {"t": t}
    for (name, role), sign in zip(channels, signs):
        log[name] = mean + offsets.get(role, 0.0) + sign * drift * (t - t0) / 3600.0 + rng.normal(0.0, noise, t.shape)
    for f in faults:
        after = t >= f.at
        if f.kind == "open":
            log[f.channel][after] = OPEN_CIRCUIT_READING
        elif after.any():
            first = np.argmax(after)
            log[f.channel][after] = log[f.channel][max(first - 1, 0)]
    return log
