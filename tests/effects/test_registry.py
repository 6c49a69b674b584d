"""The effects registry is the one home of each physical effect: every
per-point effect (acts 'kernel') has a Rust term of the same name and the
same parameters, the diagnosis library and the CLI read the registry, and a
new module in cmmpose.effects is picked up without touching anything else."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import numpy as np
import pytest

import cmmpose
import cmmpose.sim
from cmmpose import _core, effects
from cmmpose.model import LIBRARY
from cmmpose.errors import InputError


def test_every_kernel_effect_is_a_rust_term_with_the_same_parameters():
    terms = {t["name"]: t for t in _core.effect_terms()}
    kernel = {n: c for n, c in effects.available().items() if c.acts == "kernel"}
    assert set(kernel) == set(terms), set(kernel) ^ set(terms)
    for name, cls in kernel.items():
        assert list(cls.params) == terms[name]["params"], name
        # What the term reads is what the effect says the run must hold, or
        # the temperature of the sensor group the data chose for it.
        assert {n for n, _ in terms[name]["inputs"]} == set(cls.needs) - {"poses>1"} | (
            {cls.sensor_input} if cls.sensor_input else set()), name


def test_each_effect_declares_itself_once():
    for name, cls in effects.available().items():
        assert cls.name == name and cls.summary and cls.reveal and cls.params, name
        assert cls.acts in ("kernel", "pose", "length"), name
        assert "\n" not in cls.summary, name
        for p in cls.params.values():
            assert p.unit and p.prior > 0, name
        # The simulator's fields carry units.
        assert all(cls.units().values()), (name, cls.units())
        assert cls.__module__ == f"cmmpose.effects.{name.replace('-', '_')}", name


def test_diagnosis_library_and_cli_read_the_registry():
    assert list(LIBRARY) == list(effects.available())
    for name, spec in LIBRARY.items():
        cls = effects.get(name)
        assert spec.params == tuple(cls.params) and spec.physics == cls.summary and spec.effect is cls
    from click.testing import CliRunner

    from cmmpose.cli import main

    out = CliRunner().invoke(main, ["effects"], terminal_width=250).output
    for name in effects.available():
        assert name in out


def test_parse_names_the_bad_part():
    e = effects.parse("scale:x=3,z=-2")
    assert (e.x, e.y, e.z) == (3.0, 0.0, -2.0)
    with pytest.raises(InputError, match="unknown; available: squareness"):
        effects.parse("warp:x=1")
    with pytest.raises(InputError, match="'q=1' is not one of"):
        effects.parse("scale:q=1")
    with pytest.raises(InputError, match="x='abc' is not a number"):
        effects.parse("scale:x=abc")
    with pytest.raises(InputError, match="must be finite"):
        effects.get("scale")(x=float("nan"))


def test_a_new_effect_module_is_discovered(tmp_path):
    """Dropping one file into the package is all the Python side needs."""
    pkg = tmp_path / "cmmpose_effects_probe"
    code = f"""
import sys, pathlib, shutil
import cmmpose.effects as fx
src = pathlib.Path(fx.__file__).parent
dst = pathlib.Path({str(pkg)!r}) / "cmmpose" / "effects"
shutil.copytree(src.parent, dst.parent, ignore=shutil.ignore_patterns("*.so", "__pycache__", "data"))
shutil.copy2(next(src.parent.glob("_core*.so")), dst.parent)
(dst / "probe.py").write_text('''
from dataclasses import dataclass
from typing import ClassVar
from ._base import Effect, Param

@dataclass(frozen=True)
class Probe(Effect):
    name: ClassVar[str] = "probe"
    summary: ClassVar[str] = "a probe"
    reveal: ClassVar[str] = "nothing"
    params: ClassVar[dict] = {{"k": Param("mm", 1.0)}}
    acts: ClassVar[str] = "length"
    k: float = 0.0
''')
for m in [m for m in sys.modules if m.startswith("cmmpose")]:
    del sys.modules[m]
sys.path.insert(0, str(dst.parent.parent))
import cmmpose.effects as fx2
assert fx2.__file__.startswith(str(dst)), fx2.__file__
from cmmpose.model import LIBRARY
assert "probe" in fx2.available() and "probe" in LIBRARY
print("ok")
"""
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0 and res.stdout.strip() == "ok", res.stderr


def test_truth_machine_and_model_share_the_term():
    """The truth machine applies the same 'scale' term the model inverts:
    its mount point moves by ppm x reading along each axis. Tolerance 2e-7
    mm: the up to 1.2 um scale errors of Y and Z are turned by the carriage
    angles below them (about 1e-4 rad on the thesis maps)."""
    maps = cmmpose.ErrorMapSet.thesis()
    scales = np.array([[450.0, 275.0, -250.0], [800.0, 100.0, -400.0]])
    truth = cmmpose.sim.TruthMachine(maps, [effects.get("scale")(x=8.0, y=-5.0, z=3.0)])
    states = truth.states(np.zeros(2), 22.0)
    f = truth.frames(scales, states)
    thesis = cmmpose.sim.TruthMachine(maps)
    f0 = thesis.frames(scales, thesis.states(np.zeros(2), 22.0))
    dp = f["p"] - f0["p"]
    np.testing.assert_allclose(dp, scales * [8e-6, -5e-6, 3e-6], atol=2e-7)
    assert dataclasses.is_dataclass(effects.get("scale"))
