"""What ``cmmpose simulate`` was asked: one options object for the command (``cli/simulate.py``) and the artefact
runs it simulates (``cli/artefact.py``), in a module of its own so that neither command module imports the other's."""

from __future__ import annotations

import dataclasses

__all__ = ["SimulateOptions"]


@dataclasses.dataclass(frozen=True)
class SimulateOptions:
    """What ``cmmpose simulate`` was asked, from its flags (each field the click parameter of its name): one
    object for the command and :func:`cmmpose.cli.artefact.simulate_artefact`."""

    layout: str
    temperature: float
    machine_file: str | None
    maps: tuple[str, ...]
    effects: tuple[str, ...]
    speed: float
    bidirectional: bool
    jitter: float
    calibrated: bool
    reference_poses: tuple[str, ...]
    artefact: str | None
    placements: tuple[str, ...]
    seed: int
    as_json: bool
    run_dir: str
    overwrite: bool
    #: --repeat-scans; None: the default (docs/diagnosis.md).
    repeat_scans: int | None

    @classmethod
    def from_flags(cls, flags: dict) -> SimulateOptions:
        """The options from the command's click parameters (by their names)."""
        return cls(**{f.name: flags[f.name] for f in dataclasses.fields(cls)})
