"""Fuzz the entry points that read user data: mutate valid inputs at random
and count, per entry point, the inputs tried, the clear errors (a
``cmmpose.Error``), the crashes (any other exception: a traceback for the
user) and the silent results (accepted, but not what an independent
reference reads from the same bytes).

    python scripts/fuzz_inputs.py [--trials 300] [--seed 0]

Exit status 1 if any entry point had a crash or a silent result. The
references are deliberately simple and independent of cmmpose's readers:
Python's csv module and a strict number pattern for text files, numpy's own
loader for .npy, value equality with the clean file for binary run tables,
and tests/support/numpy_reference.py for the compensation.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import re
import shutil
import sys
import tempfile
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import cmmpose
from cmmpose.model import Model
from cmmpose.formats.pointfiles import read_points
from cmmpose.run import Run

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests" / "support"))
import numpy_reference as ref  # noqa: E402  (the independent NumPy implementation)

NUMBER = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
#: Point files may hold NaN or inf (compensate's nan_policy decides); map files may not.
POINT_NUMBER = re.compile(NUMBER.pattern + r"|[+-]?(?:nan|inf)", re.IGNORECASE)
#: Tokens a mutation puts into a text field.
TOKENS = ["", " ", "nan", "inf", "-inf", "1_0", "\u0661\u0660", "0x10", "1e400", "true", "12.7.1", "1,2", "-",
          "\u00b5", "1e-400", "+5", "  7  ", "9" * 40, "None", "\"3\""]


@dataclass
class Counts:
    tried: int = 0
    errors: int = 0
    crashes: int = 0
    silent: int = 0
    accepted: int = 0
    examples: list = field(default_factory=list)

    def note(self, kind: str, what: str) -> None:
        setattr(self, kind, getattr(self, kind) + 1)
        if kind in ("crashes", "silent") and len(self.examples) < 5:
            self.examples.append(what)


def _mutate_text(text: str, rng: np.random.Generator) -> str:
    """One random edit: a field replaced by a token, a field or line added or
    removed, a separator changed, the text cut short or re-encoded."""
    lines = text.split("\n")
    k = int(rng.integers(len(lines)))
    fields = lines[k].split(",")
    op = int(rng.integers(7))
    if op == 0:
        fields[int(rng.integers(len(fields)))] = TOKENS[int(rng.integers(len(TOKENS)))]
    elif op == 1:
        fields.insert(int(rng.integers(len(fields) + 1)), TOKENS[int(rng.integers(len(TOKENS)))])
    elif op == 2 and len(fields) > 1:
        del fields[int(rng.integers(len(fields)))]
    elif op == 3:
        lines.insert(k, lines[int(rng.integers(len(lines)))])
    elif op == 4 and len(lines) > 1:
        del lines[k]
        return "\n".join(lines)
    elif op == 5:
        return text[: int(rng.integers(len(text) + 1))]
    else:
        fields = [f.replace(".", ",") if rng.random() < 0.3 else f for f in fields]
    lines[k] = ",".join(fields)
    return "\n".join(lines)


def _classify(counts: Counts, call, oracle, what: str) -> None:
    """Run ``call``; compare with ``oracle()`` (the reference's value, or
    None where the reference rejects the input)."""
    counts.tried += 1
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            got = call()
    except cmmpose.Error:
        counts.note("errors", what)
        return
    except Exception as exc:  # noqa: BLE001 - counting them is the point
        counts.note("crashes", f"{what}: {type(exc).__name__}: {exc}"[:300])
        return
    counts.accepted += 1
    want = oracle()
    if want is None or not _same(got, want):
        counts.note("silent", what)


def _same(a, b) -> bool:
    if isinstance(a, tuple):
        return isinstance(b, tuple) and len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if a is None or b is None:
        return a is None and b is None
    a, b = np.asarray(a), np.asarray(b)
    if a.dtype.kind not in "fc" or b.dtype.kind not in "fc":
        return a.shape == b.shape and bool(np.all(a == b))
    return a.shape == b.shape and np.array_equal(a, b, equal_nan=True)


# -- point CSV ---------------------------------------------------------------------------

def _reference_points_csv(raw: bytes):
    """A strict reading of a point CSV, or None if it is not one."""
    if raw.startswith(b"\xef\xbb\xbf"):
        raw = raw[3:]
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        return None
    rows = [r for r in csv.reader(io.StringIO(text))]
    if not rows:
        return None
    header = [h.strip() for h in rows[0]]
    need = ["u", "v", "D", "E", "F"]
    if any(h not in header for h in need) or len(set(h for h in header if h)) != len([h for h in header if h]):
        return None
    body = [r for r in rows[1:] if any(x.strip() for x in r) and "".join(r).strip()]
    vals = []
    for r in body:
        if len(r) != len(header) or not all(POINT_NUMBER.fullmatch(x.strip()) for x in r):
            return None
        vals.append([float(x) for x in r])
    a = np.array(vals, dtype=float).reshape(-1, len(header))
    cols = [header.index(c) for c in need]
    t = a[:, header.index("T")] if "T" in header else None
    return a[:, cols[:2]], a[:, cols[2:]], t


def fuzz_points_csv(n: int, rng, tmp: Path) -> Counts:
    c = Counts()
    seed = "u,v,D,E,F,T\n" + "\n".join(f"{i * 0.5:g},{-i:g},{450 + i:g},275.5,-250,{22 + 0.1 * i:g}" for i in range(6)) + "\n"
    for k in range(n):
        text = _mutate_text(seed, rng)
        raw = text.encode("utf-16" if rng.random() < 0.03 else "latin-1" if rng.random() < 0.05 else "utf-8",
                          errors="replace")
        p = tmp / f"p{k}.csv"
        p.write_bytes(raw)
        _classify(c, lambda: read_points(p), lambda: _reference_points_csv(raw), f"points csv #{k}: {text[:60]!r}")
    return c


# -- point NPY ---------------------------------------------------------------------------

def fuzz_points_npy(n: int, rng, tmp: Path) -> Counts:
    c = Counts()
    base = np.column_stack([np.arange(8.0), -np.arange(8.0), 450 + np.arange(8.0), np.full(8, 275.0),
                            np.full(8, -250.0)])
    variants = [base, base.astype(np.float32), base.astype(np.int64), base.astype(complex), base.astype(str),
                base[:, :4], base.T, base[:0], np.zeros((2, 5), bool), base.reshape(2, 4, 5)]
    for k in range(n):
        a = variants[int(rng.integers(len(variants)))]
        buf = io.BytesIO()
        np.save(buf, a)
        raw = bytearray(buf.getvalue())
        op = int(rng.integers(4))
        if op == 1:  # a byte of the header changed
            i = int(rng.integers(min(len(raw), 128)))
            raw[i] = int(rng.integers(256))
        elif op == 2:  # cut short
            raw = raw[: int(rng.integers(len(raw) + 1))]
        elif op == 3:  # a lying shape
            raw = bytearray(bytes(raw).replace(b"(8, 5)", b"(10000000000000, 5)", 1))
        p = tmp / f"p{k}.npy"
        p.write_bytes(bytes(raw))

        def reference(p=p):
            try:
                r = np.load(p, allow_pickle=False)
            except Exception:  # noqa: BLE001
                return None
            if not isinstance(r, np.ndarray) or r.dtype.kind not in "iuf" or r.ndim != 2 or r.shape[1] not in (5, 6):
                return None
            r = r.astype(float)
            return r[:, :2], r[:, 2:5], (r[:, 5] if r.shape[1] == 6 else None)

        _classify(c, lambda p=p: read_points(p), reference, f"points npy #{k} (op {op})")
    return c


# -- map files ---------------------------------------------------------------------------

def _reference_map(raw: bytes):
    """The tables of a canonical map CSV read strictly, or None."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        return None
    body = [ln for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]
    if not body or body[0].split(",")[:2] != ["carriage", "position_mm"]:
        return None
    rows = {}
    for ln in body[1:]:
        f = ln.split(",")
        if len(f) != 8 or f[0].strip() not in ("X", "Y", "Z") or not all(NUMBER.fullmatch(x.strip()) for x in f[1:]):
            return None
        v = [float(x) for x in f[1:]]
        if not all(np.isfinite(v)):
            return None
        rows.setdefault(f[0].strip(), []).append(v)
    if set(rows) != {"X", "Y", "Z"}:
        return None
    return tuple(np.array(rows[a]) for a in "XYZ")


def fuzz_map_csv(n: int, rng, tmp: Path) -> Counts:
    c = Counts()
    m = cmmpose.ErrorMapSet.thesis().maps[0]
    p0 = tmp / "map.csv"
    m.write(p0)
    seed = p0.read_text()
    lines = seed.split("\n")
    # The rows are cut down below, so the writer's self-check lines (rows, sha256) go: the
    # mutated files are then read as hand-made maps are (with a note), and judged by the reference.
    head = [ln for ln in lines if ln.startswith("#") and not ln.startswith(("# rows:", "# sha256:"))]
    rows = [ln for ln in lines if ln and not ln.startswith("#")]
    small = "\n".join(head + rows[:1] + [r for r in rows[1:] if r.split(",")[1] in ("0", "25", "50", "-25", "-50")]) + "\n"
    for k in range(n):
        text = _mutate_text(small, rng)
        raw = text.encode("utf-8")
        p = tmp / f"m{k}.csv"
        p.write_bytes(raw)

        def call(p=p):
            mm = cmmpose.ErrorMap.read(p)
            return tuple(np.asarray(mm.table(a)) for a in "XYZ")

        def reference(raw=raw):
            r = _reference_map(raw)
            if r is None:
                return None
            # Rows as the reader keeps them: sorted by position (it refuses duplicates).
            return tuple(t[np.argsort(t[:, 0], kind="stable")] for t in r)

        _classify(c, call, reference, f"map csv #{k}: {text[-80:]!r}")
    return c


# -- run directories ---------------------------------------------------------------------

def fuzz_run_dir(n: int, rng, tmp: Path, run: Run) -> Counts:
    c = Counts()
    clean_dir = tmp / "clean"
    run.save(clean_dir)
    files = ["points.parquet", "scans.parquet", "poses.parquet", "temperatures.parquet"]
    doc = json.loads((clean_dir / "run.json").read_text())
    for k in range(n):
        d = tmp / f"r{k}"
        shutil.copytree(clean_dir, d)
        json_edit = rng.random() < 0.4
        if json_edit:  # a value in run.json replaced by one of another type or a strange one
            bad = json.loads(json.dumps(doc))
            key = ["schema_version", "artefact", "maps", "temperature_channels", "created"][int(rng.integers(5))]
            choices = ["12.7", True, None, [], {}, 1e308, -1, "x" * 3]
            if key == "artefact":
                bad["artefact"]["ball_radius_mm"] = choices[int(rng.integers(len(choices)))]
            elif key == "temperature_channels":
                bad["temperature_channels"][0]["role"] = choices[int(rng.integers(len(choices)))]
            else:
                bad[key] = choices[int(rng.integers(len(choices)))]
            (d / "run.json").write_text(json.dumps(bad))
        else:  # one flipped bit in a table
            f = d / files[int(rng.integers(len(files)))]
            b = bytearray(f.read_bytes())
            i = int(rng.integers(len(b)))
            b[i] ^= 1 << int(rng.integers(8))
            f.write_bytes(bytes(b))

        def reference(json_edit=json_edit):
            # A table bit flip must not change what loads; a run.json edit that
            # loads must keep the numbers the evaluation uses.
            return ("same",)

        def call(d=d, json_edit=json_edit):
            got = Run.load(d)
            same = all(np.array_equal(got.points[k2], run.points[k2]) for k2 in run.points) and \
                all(np.array_equal(np.asarray(got.temperatures[k2]), np.asarray(run.temperatures[k2]))
                    for k2 in run.temperatures)
            if json_edit:
                r = got.artefact.get("ball_radius_mm", 1.0)
                same = same and isinstance(r, (int, float)) and not isinstance(r, bool) and r > 0
            return ("same",) if same else ("changed",)

        _classify(c, call, reference, f"run dir #{k} ({'run.json' if json_edit else 'table bit'})")
        shutil.rmtree(d)
    return c


# -- model files -------------------------------------------------------------------------

def fuzz_model_json(n: int, rng, tmp: Path) -> Counts:
    c = Counts()
    good = Model(cmmpose.ErrorMapSet.thesis()).with_values("squareness", [1.0, 2.0, 3.0]).to_dict()
    for k in range(n):
        doc = json.loads(json.dumps(good))
        op = int(rng.integers(5))
        if op == 0:
            doc["maps"]["kind"] = ["sett", "Map", "", 1, None][int(rng.integers(5))]
        elif op == 1:
            doc["maps"]["csv"] = doc["maps"]["csv"][: int(rng.integers(3))]
        elif op == 2:
            doc["effects"][0]["params"]["xy"] = ["1", True, None, float("1e308")][int(rng.integers(4))]
        elif op == 3:
            doc["schema_version"] = [2, "1", True][int(rng.integers(3))]
        else:
            doc["maps"]["csv"][0] = _mutate_text(doc["maps"]["csv"][0], rng)
        p = tmp / f"model{k}.json"
        p.write_text(json.dumps(doc))

        def call(p=p):
            m = Model.load(p)
            first = m.maps.maps[0] if isinstance(m.maps, cmmpose.ErrorMapSet) else m.maps
            return (len(m.maps.maps) if isinstance(m.maps, cmmpose.ErrorMapSet) else 1,
                    tuple(float(x) for x in m.values("squareness")),
                    tuple(np.asarray(first.table(a)) for a in "XYZ"))

        def reference(doc=doc):
            if doc["maps"]["kind"] != "set" or len(doc["maps"]["csv"]) < 1 or doc["schema_version"] != 1:
                return None
            tables = [_reference_map(t.encode()) for t in doc["maps"]["csv"]]
            if any(t is None for t in tables):
                return None
            xy = doc["effects"][0]["params"]["xy"]
            if isinstance(xy, bool) or not isinstance(xy, (int, float)) or not np.isfinite(xy):
                return None
            # The reader sorts rows by position (the set of maps by temperature; one changed map stays first
            # here because only the first map's text is edited and temperatures are in the header).
            first = tuple(t[np.argsort(t[:, 0], kind="stable")] for t in tables[0])
            return (len(tables), (float(xy), 2.0, 3.0), first)
        _classify(c, call, reference, f"model json #{k} (op {op})")
    return c


# -- compensation ------------------------------------------------------------------------

def fuzz_compensate(n: int, rng) -> Counts:
    c = Counts()
    maps = cmmpose.ErrorMapSet.thesis()
    pose, offset = (90.0, 90.0, 0.0), (1.001, 264.505, 129.575)
    for k in range(n):
        m = int(rng.integers(0, 6))
        uv = rng.uniform(-30, 30, (m, 2))
        scales = np.column_stack([rng.uniform(0, 900, m), rng.uniform(0, 550, m), rng.uniform(-500, 0, m)])
        t = rng.uniform(20, 30, m)
        op = int(rng.integers(6))
        if op == 1 and m:
            uv[int(rng.integers(m)), int(rng.integers(2))] = [np.nan, np.inf, 1e308, -1e308][int(rng.integers(4))]
        elif op == 2 and m:
            scales[int(rng.integers(m)), int(rng.integers(3))] = [2000.0, -1e9, np.nan, 1.7e308][int(rng.integers(4))]
        elif op == 3 and m:
            t[int(rng.integers(m))] = [19.7, 30.4, 35.0, np.nan][int(rng.integers(4))]
        elif op == 4:
            uv = uv.astype([np.float32, complex, bool, np.int16][int(rng.integers(4))])
        elif op == 5:
            scales = scales[:, :2] if rng.random() < 0.5 else np.asfortranarray(scales)
        uv_in, s_in, t_in = uv.copy(), np.array(scales, copy=True), t.copy()

        def call(uv=uv, scales=scales, t=t):
            return cmmpose.compensate(uv, scales, maps, pose, offset, t)

        def reference(uv=uv, scales=scales, t=t):
            if uv.dtype.kind not in "iuf" or np.asarray(scales).shape[1:] != (3,):
                return None
            # The policy: temperatures within 0.5 K of the maps are held at the edge.
            tt = np.asarray(t, float)
            if not (np.all(np.isfinite(uv)) and np.all(np.isfinite(scales)) and np.all(np.isfinite(tt))):
                return None
            if np.any((tt < 19.5) | (tt > 30.5)):
                return None
            dicts = [{"temperature": mm.temperature, "squareness": mm.squareness, **{a: mm.table(a) for a in "XYZ"}}
                     for mm in maps.maps]
            out = ref.compensate(np.asarray(uv, float), np.asarray(scales, float), dicts, pose, offset,
                                 np.clip(tt, 20, 30))
            return out if np.all(np.isfinite(out)) else None

        def check(uv=uv, scales=scales, t=t):
            got = call()
            want = reference()
            if want is not None and got.shape == want.shape and np.allclose(got, want, rtol=1e-12, atol=1e-9):
                return ("ok",)
            return ("different",)

        _classify(c, check, lambda: ("ok",), f"compensate #{k} (op {op})")
        if not (np.array_equal(uv, uv_in, equal_nan=True) and np.array_equal(scales, s_in, equal_nan=True)
                and np.array_equal(t, t_in, equal_nan=True)):
            c.note("silent", f"compensate #{k}: an input was modified")
    return c


def run_all(trials: int = 300, seed: int = 0) -> dict[str, Counts]:
    """Fuzz every entry point with ``trials`` inputs each."""
    from cmmpose.sim.runs import simulate_ballbar_run
    from cmmpose.sim.scanner import Scanner

    rng = np.random.default_rng(seed)
    out = {}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        out["read_points (CSV)"] = fuzz_points_csv(trials, rng, tmp)
        out["read_points (NPY)"] = fuzz_points_npy(trials, rng, tmp)
        out["ErrorMap.read (CSV)"] = fuzz_map_csv(trials, rng, tmp)
        out["Model.load"] = fuzz_model_json(trials, rng, tmp)
        run, _ = simulate_ballbar_run(cmmpose.ErrorMapSet.thesis(), 22.5, layout="crossed",
                                      scanner=Scanner(points_per_profile=32), seed=seed)
        out["Run.load"] = fuzz_run_dir(max(trials // 3, 1), rng, tmp, run)
        out["compensate"] = fuzz_compensate(trials, rng)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trials", type=int, default=300, help="inputs per entry point (run directories: a third)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    results = run_all(args.trials, args.seed)
    print(f"{'entry point':24s} {'tried':>6s} {'errors':>7s} {'accepted':>8s} {'crashes':>8s} {'silent':>7s}")
    bad = 0
    for name, c in results.items():
        print(f"{name:24s} {c.tried:6d} {c.errors:7d} {c.accepted:8d} {c.crashes:8d} {c.silent:7d}")
        for e in c.examples:
            print(f"    {e}")
        bad += c.crashes + c.silent
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
