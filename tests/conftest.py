"""What the tests share: a fixed console width, and one simulated run, one plate run and one machine.

The console width. Rich lays text out at ``COLUMNS`` when it is set, else at the terminal's width, else at 80
columns; a console made while ``COLUMNS`` is set keeps that width (``cmmpose.cli.common.console`` is made when
the command line is imported). So ``COLUMNS`` is unset here, before any test module imports cmmpose, and every
test runs at 80 columns, the width a run without a terminal gets (CI, nohup): a shell that exports its own
``COLUMNS`` changes nothing. A test that reads the console at another width says so
(``CliRunner().invoke(..., env={"COLUMNS": "100"})`` or ``Console(width=...)``). Text that holds a temporary
path is compared with its whitespace folded (``" ".join(output.split())``), since the path's length moves
where a line wraps.

The shared fixtures are made once per session and are read-only (a ``Run`` never changes once made; a test
that needs another run derives one, e.g. with ``dataclasses.replace``, or saves it under ``tmp_path``).

The layout. The folders of ``tests/`` mirror ``python/cmmpose/`` (docs/architecture.md, "Tests"); a folder's own
``conftest.py`` holds what only its tests share; the helper modules (the independent references, NIST's scans,
``repo.REPO`` for the repository's files) live in ``tests/support/``, imported by name (``pythonpath`` in
pyproject.toml).
"""

from __future__ import annotations

import os

import pytest

os.environ.pop("COLUMNS", None)  # before cmmpose.cli's console is made (see above)

#: The width every test's console has unless the test sets another.
CONSOLE_COLUMNS = "80"


@pytest.fixture(autouse=True)
def _console_width(monkeypatch):
    monkeypatch.setenv("COLUMNS", CONSOLE_COLUMNS)


@pytest.fixture(scope="session")
def machine():
    """The thesis machine (``Machine.thesis()``: the DEA Iota 1102, its maps, the Hyscan 45C, its mount and
    thermocouples), what every command assumes without ``--machine``."""
    from cmmpose.machine import Machine

    return Machine.thesis()


@pytest.fixture(scope="session")
def simulated_run():
    """One small simulated ballbar run: the crossed layout (8 positions) on the thesis maps at 22.5 C, 64 points a
    profile, seed 1; a ``Run``, whose truth the tests that use it do not need."""
    import cmmpose
    from cmmpose.sim import Scanner, simulate_ballbar_run

    run, _ = simulate_ballbar_run(cmmpose.ErrorMapSet.thesis(), 22.5, layout="crossed",
                                  scanner=Scanner(points_per_profile=64), seed=1)
    return run


@pytest.fixture(scope="session")
def plate_run():
    """One simulated plate run: a KOBA 0320 ball plate at two placements (``xy@z=-525`` and the same turned by 90
    degrees) on the thesis machine with its maps (uncompensated errors of ~0.1 mm), scanner noise on, 24 C,
    seed 5; a ``Run``."""
    from cmmpose import artefacts
    from cmmpose.sim.artefact_runs import simulate_artefact_run

    run, _ = simulate_artefact_run(artefacts.load_artefact("koba-0320"), ["xy@z=-525", "xy@z=-525,rot=90"], None,
                                   24.0, seed=5)
    return run
