"""The live display of ``cmmpose acquire`` (rich): records per second of each
stream, rejections by reason, gaps, resets, reconnects, timeouts, the latest
temperatures, the age of the last disk flush and the buffer's fill."""

from __future__ import annotations

from rich.console import Group
from rich.table import Table
from rich.text import Text

from .stats import Snapshot

__all__ = ["render"]


def _rejected(d: dict) -> str:
    if not d["rejected"]:
        return "0"
    return f"{d['rejected_total']} (" + ", ".join(f"{k} {v}" for k, v in sorted(d["rejected"].items())) + ")"


def render(snap: Snapshot, title: str = "cmmpose acquire") -> Group:
    """A rich renderable of one snapshot.

    Parameters
    ----------
    snap : Snapshot
        From ``Recorder.snapshot``.
    title : str
        Table title.
    """
    t = Table(title=f"{title}  ({snap.elapsed:.0f} s)", show_lines=False)
    t.add_column("")
    t.add_column("scanner", justify="right")
    t.add_column("thermo", justify="right")
    s, h = snap.scanner, snap.thermo

    def row(label, f):
        t.add_row(label, f(s), f(h))

    row("port", lambda d: (d["port"] or "-") + ("" if d["connected"] or not d["port"] else " [red](disconnected)[/red]"))
    row("records", lambda d: f"{d['records']:,}")
    row("records/s", lambda d: f"{d['rate']:.1f}")
    t.add_row("points", f"{s['points']:,}", "")
    row("rejected", _rejected)
    t.add_row("gaps (missing)", f"{s['gaps']} ({s['missing']})", "")
    row("resets", lambda d: str(d["resets"]))
    row("reconnects", lambda d: str(d["reconnects"]))
    row("timeouts", lambda d: str(d["timeouts"]))
    row("backpressure (s)", lambda d: f"{d['backpressure_s']:.2f}")
    temps = Table(title="latest temperatures (C)", show_header=True)
    names = list(snap.latest_temperatures)
    for n in names:
        temps.add_column(n, justify="right")
    if names:
        temps.add_row(*(f"{snap.latest_temperatures[n]:.3f}" for n in names))
    age = "-" if snap.flush_age is None else f"{snap.flush_age:.2f} s"
    foot = Text(f"last flush {age} ago | {snap.blocks} blocks, {snap.journal_bytes / 1e6:.1f} MB | buffer "
                f"{snap.buffer_bytes / 1e6:.1f}/{snap.buffer_capacity / 1e6:.0f} MB (peak {snap.buffer_high_water / 1e6:.1f}) | "
                f"backpressure {snap.backpressure_stalls} stalls, {snap.backpressure_seconds:.2f} s")
    errs = [f"{k}: {d['last_error']}" for k, d in (("scanner", s), ("thermo", h)) if d["last_error"] and not d["connected"]]
    return Group(t, temps, foot, *(Text(e, style="red") for e in errs))


def summary_table(run, run_dir) -> Table:
    """A table of what a finished recording holds (from ``run.metadata['acquisition']``)."""
    a = run.metadata.get("acquisition", {})
    t = Table(title=f"cmmpose acquire -> {run_dir}", show_header=False)
    for name in ("scanner", "thermo"):
        s = a.get(name, {})
        rej = s.get("rejected", {})
        t.add_row(f"{name} records", f"{s.get('records', 0):,}")
        t.add_row(f"{name} rejected", ", ".join(f"{k} {v}" for k, v in rej.items()) or "0")
        t.add_row(f"{name} gaps / missing / resets / reconnects / timeouts",
                  f"{s.get('gaps', 0)} / {s.get('missing', 0)} / {s.get('resets', 0)} / {s.get('reconnects', 0)} / {s.get('timeouts', 0)}")
    t.add_row("points", f"{run.n_points:,} in {len(run.scans['scan_id'])} scans")
    c = a.get("clock", {}).get("thermo_to_scanner")
    if c:
        t.add_row("logger -> scanner clock", f"offset {c['offset_s']:.6f} s, drift {c['drift_ppm']:.1f} ppm")
    bp = a.get("backpressure", {})
    t.add_row("backpressure", f"{bp.get('stalls', 0)} stalls, {bp.get('seconds', 0.0):.2f} s")
    tail = a.get("journal", {}).get("torn_tail")
    t.add_row("journal", f"{a.get('journal', {}).get('blocks', 0)} blocks" + (f", torn tail of {tail['nbytes']} bytes ({tail['reason']})" if tail else ", no torn tail"))
    return t


def record_live(run_dir, scanner, thermo, *, duration=None, console=None, show=True, **options):
    """Record with a live display until ``duration`` s pass or SIGINT/SIGTERM
    (Ctrl-C stops cleanly: the run is closed, never cut), then return the run.

    Parameters
    ----------
    run_dir : str or path-like
        The run directory.
    scanner, thermo : str or None
        Ports (pyserial URLs).
    duration : float, optional
        Seconds to record.
    console : rich.console.Console, optional
        Where the display goes.
    show : bool
        Show the live display.
    **options
        ``Recorder`` options.
    """
    import signal
    import threading

    from rich.live import Live

    from .recorder import acquire

    stop = threading.Event()
    old = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        if not show:
            return acquire(run_dir, scanner, thermo, duration=duration, stop=stop, **options)
        with Live(console=console, refresh_per_second=4, transient=False) as live:
            return acquire(run_dir, scanner, thermo, duration=duration, stop=stop,
                           on_update=lambda snap: live.update(render(snap)), **options)
    finally:
        for s, h in old.items():
            signal.signal(s, h)
