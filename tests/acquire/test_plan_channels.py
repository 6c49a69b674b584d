"""Which thermocouple channels a recording uses: the plan file's when it lists
them, else the machine file's (cmmpose.acquire.plan.Plan.with_machine_channels,
the library home of what `cmmpose acquire --machine` does)."""

from __future__ import annotations

import json

import pytest
from cmmpose.acquire.plan import Plan
from cmmpose.errors import AcquisitionError


def test_a_plan_without_channels_takes_the_machines_in_order(machine):
    plan = Plan().with_machine_channels(machine)
    assert [(c["name"], c["role"], c["channel"]) for c in plan.temperature_channels] == [
        (name, role, 101 + k) for k, (name, role) in enumerate(machine.thermocouples.items())]


def test_a_plan_that_lists_channels_keeps_them(tmp_path, machine):
    listed = [{"name": "T1", "role": "x_scale", "channel": 105}]
    path = tmp_path / "plan.json"
    path.write_text(json.dumps({"temperature_channels": listed}))
    plan = Plan.read(path)
    assert plan.with_machine_channels(machine) is plan
    assert plan.temperature_channels == listed


def test_the_machines_channels_are_checked_like_a_plans():
    class Odd:
        thermocouples = {"T1": "no-such-role"}

    with pytest.raises(AcquisitionError, match="role"):
        Plan().with_machine_channels(Odd())
