"""The scheduler a scale-out runs on (docs/scale-out.md): a spec checked without connecting, a client opened
(a scheduler at an address probed first, so that no Dask connection hangs), results gathered in order.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import socket
import struct
import time

from ..errors import SchedulerError

_log = logging.getLogger("cmmpose.scale")

#: The local scheduler specs; anything else must be an address ``tcp://host:port``.
SCHEDULERS = ("threads", "processes")
#: s: how long a scheduler at an address may take to accept the connection and
#: greet (``scheduler_timeout=``, ``--scheduler-timeout``; docs/scale-out.md).
SCHEDULER_TIMEOUT = 10.0
#: Address schemes a spec may have: ``tcp`` (probed, then connected) and
#: ``tls`` (Dask's TLS settings from its configuration).
_SCHEMES = ("tcp", "tls")
#: bytes: a Dask handshake's frames are a few hundred; a length beyond this is no Dask scheduler.
_MAX_GREETING = 1 << 20
#: Characters of a bad value echoed back in a message.
_ECHO = 40


def require_distributed():
    """The ``distributed`` module, or a clear error without the extra."""
    try:
        import dask  # noqa: F401
        import distributed
    except ImportError as exc:
        raise SchedulerError(f"scheduling needs the dask extra (missing module {exc.name!r}): "
                             f"pip install 'cmmpose[dask]'") from None
    return distributed


def check_scheduler(scheduler):
    """The scheduler spec if it is well formed, else ``SchedulerError`` saying
    what it must be (no connection is made).

    Parameters
    ----------
    scheduler : str or distributed.Client
        ``'threads'``, ``'processes'``, an address ``tcp://host:port`` (or
        ``tls://host:port``), or a Client.

    Returns
    -------
    str or distributed.Client
        ``scheduler``, unchanged.
    """
    if not isinstance(scheduler, str):
        if isinstance(scheduler, require_distributed().Client):
            return scheduler
        raise SchedulerError(f"scheduler: expected 'threads', 'processes' or an address tcp://host:port, "
                             f"got {_echo(repr(scheduler))}")
    if scheduler in SCHEDULERS:
        return scheduler
    must = "'threads', 'processes' or an address tcp://host:port (a Dask scheduler's, usually port 8786)"
    if "://" not in scheduler:
        raise SchedulerError(f"scheduler: expected {must}, got {_echo(repr(scheduler))}")
    scheme, _, rest = scheduler.partition("://")
    if scheme.lower() not in _SCHEMES:
        web = " (an http:// address is a web page, such as the dashboard, not the scheduler)" \
            if scheme.lower() in ("http", "https") else ""
        raise SchedulerError(f"scheduler {_echo(scheduler)}: the address must be tcp://host:port{web}; "
                             f"the spec is {must}")
    host, _, port = rest.rstrip("/").rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise SchedulerError(f"scheduler {_echo(scheduler)}: expected {scheme}://host:port with a port 1..65535 "
                             f"(a Dask scheduler's, usually 8786)")
    return scheduler


def _echo(text: str) -> str:
    """``text``, cut to its first characters when long (a bad value echoed back)."""
    return text if len(text) <= _ECHO else text[:_ECHO] + "..."


def _probe_scheduler(address: str, timeout: float) -> None:
    """Connect to ``address`` (``tcp://host:port``) and wait for a Dask
    scheduler's greeting: a scheduler sends its handshake first, a few
    hundred bytes after an 8-byte length. ``SchedulerError`` naming the
    address and what did not answer if nothing accepts the connection, the
    peer says nothing within ``timeout`` s, or what it says is not Dask's."""
    scheme, _, rest = address.partition("://")
    host, _, port = rest.rstrip("/").rpartition(":")
    host = host.strip("[]")  # an IPv6 literal
    limit = f"{timeout:g} s"
    deadline = time.monotonic() + timeout
    try:
        sock = socket.create_connection((host, int(port)), timeout=timeout)
    except TimeoutError:
        raise SchedulerError(f"scheduler {address}: nothing accepted the connection within {limit}", value=timeout,
                             unit="s", option="scheduler_timeout", remedy="scheduler_timeout") from None
    except OSError as exc:
        raise SchedulerError(f"scheduler {address}: cannot connect ({exc.strerror or exc})") from None
    if scheme.lower() != "tcp":
        sock.close()  # a TLS server waits for the client's hello: Dask's own connect timeout bounds the rest
        return
    head = b""
    with sock:
        while len(head) < 8:
            left = deadline - time.monotonic()
            if left <= 0:
                break
            sock.settimeout(left)
            try:
                chunk = sock.recv(8 - len(head))
            except TimeoutError:
                break
            except OSError as exc:
                raise SchedulerError(f"scheduler {address}: the connection failed before the Dask scheduler "
                                     f"greeted ({exc.strerror or exc})") from None
            if not chunk:
                raise SchedulerError(f"scheduler {address}: accepted the connection, then closed it without the "
                                     f"Dask handshake: is a Dask scheduler listening there?") from None
            head += chunk
    if len(head) < 8:
        raise SchedulerError(f"scheduler {address}: accepted the connection but sent no Dask handshake within "
                             f"{limit}", value=timeout, unit="s", option="scheduler_timeout",
                             remedy="scheduler_handshake")
    if min(struct.unpack("<Q", head)[0], struct.unpack(">Q", head)[0]) > _MAX_GREETING:
        said = head.split(b"\r")[0].decode("ascii", "replace")
        raise SchedulerError(f"scheduler {address}: answered, but not as a Dask scheduler (it began {said!r}; "
                             f"an HTTP server such as the dashboard?): the address must be the Dask scheduler's "
                             f"tcp://host:port (usually port 8786), or give 'threads' or 'processes'")


@contextlib.contextmanager
def scheduler_client(scheduler="threads", *, n_workers: int | None = None,
                     timeout: float = SCHEDULER_TIMEOUT):
    """A ``distributed.Client`` for a scheduler spec, closed on exit (with its
    local cluster) unless it was given.

    Parameters
    ----------
    scheduler : str or distributed.Client
        ``'threads'``: a worker in this process with one thread per core (no
        pickling of data); ``'processes'``: a local cluster of ``n_workers``
        single-threaded worker processes; ``'tcp://host:port'``: the running
        scheduler at that address; or a Client, yielded as it is.
    n_workers : int, optional
        Worker processes for ``'processes'`` (default: one per core).
    timeout : float
        s: at an address, the longest wait for the scheduler to accept the
        connection and for its greeting (the Dask handshake), and Dask's
        connect timeout (``distributed.comm.timeouts.connect``); default
        :data:`SCHEDULER_TIMEOUT`.

    Raises
    ------
    SchedulerError
        Without the dask extra, for a malformed spec (an ``http://`` address,
        a missing port), or when the scheduler at the address cannot be
        reached or does not answer within ``timeout`` (the message names the
        address and what did not answer).
    """
    if isinstance(timeout, bool) or not isinstance(timeout, (int, float)) or not 0 < timeout < math.inf:
        raise SchedulerError(f"scheduler_timeout: expected a positive number of seconds, got {_echo(repr(timeout))}")
    distributed = require_distributed()
    if isinstance(scheduler, distributed.Client):
        yield scheduler
        return
    check_scheduler(scheduler)
    cores = os.cpu_count() or 1
    with contextlib.ExitStack() as stack:
        if scheduler == "threads":
            cluster = stack.enter_context(distributed.LocalCluster(
                processes=False, n_workers=1, threads_per_worker=cores, dashboard_address=":0"))
            address = cluster
        elif scheduler == "processes":
            # One kernel thread per worker process (Dask's nanny already sets OMP_NUM_THREADS=1,
            # which sizes Arrow's pool): the workers share the cores instead of oversubscribing them.
            cluster = stack.enter_context(distributed.LocalCluster(
                processes=True, n_workers=n_workers or cores, threads_per_worker=1, dashboard_address=":0",
                env={"RAYON_NUM_THREADS": "1"}))
            address = cluster
        else:
            # Dask bounds the TCP connect but not the wait for the scheduler's greeting (a port that accepts
            # and never answers hangs it; an HTTP server's answer is read as a 3 EiB message): probe first.
            _probe_scheduler(scheduler, float(timeout))
            address = scheduler
        import dask

        try:
            with dask.config.set({"distributed.comm.timeouts.connect": f"{float(timeout)}s"}):
                client = stack.enter_context(distributed.Client(address, timeout=f"{float(timeout)}s"))
        except (OSError, TimeoutError, ValueError, MemoryError) as exc:
            raise SchedulerError(f"scheduler {scheduler}: cannot connect within {float(timeout):g} s "
                                 f"({type(exc).__name__}: {exc})") from None
        _log.info("scheduler %s: %d workers", scheduler, len(client.scheduler_info().get("workers", {})))
        yield client


def gather_results(client, futures, progress=None):
    """Results of ``futures`` in order; ``progress(done, total)`` after each.
    On an error the rest are cancelled and the first error is raised."""
    distributed = require_distributed()
    index = {f.key: i for i, f in enumerate(futures)}
    out = [None] * len(futures)
    try:
        for done, fut in enumerate(distributed.as_completed(futures), start=1):
            out[index[fut.key]] = fut.result()
            if progress is not None:
                progress(done, len(futures))
    except BaseException:
        client.cancel(futures)
        raise
    return out
