"""The Dask side of a sweep: the local cluster (its workers deaf to Ctrl-C, killed at once on an interrupt),
a client of an existing scheduler (its address checked before any work, its handshake bounded in time), and
the number of cores. :func:`kinredund.sweep.run.sweep` runs its batches on the client :func:`dask_client`
gives.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import socket
import threading

from kinredund.errors import KinredundError

#: environment of the local cluster's workers: one BLAS/OpenMP thread each (the work is many small
#: matrices; more threads per process only compete for the cores)
WORKER_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
#: how long connecting to a Dask scheduler may take [s]: connection and Dask's handshake (a server that
#: accepts the connection but does not speak Dask's protocol, such as an HTTP server, never answers it)
CONNECT_TIMEOUT = 10.0


def default_workers() -> int:
    """The cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def check_scheduler(address) -> str:
    """``address`` if it is the address of a Dask scheduler (``tcp://host:port``), else KinredundError.

    Checked before any work with distributed's own parser, so that a malformed address (no port, a port
    that is not a number or out of range, an unknown scheme such as ``http``) is named as bad input.
    """
    from distributed.comm.addressing import parse_address, parse_host_port
    from distributed.comm.registry import get_backend

    hint = "give the scheduler's address as tcp://host:port (e.g. tcp://127.0.0.1:8786)"
    if not isinstance(address, str) or not address.strip():
        raise KinredundError(f"the Dask scheduler address must be a non-empty string: {hint}; got {address!r}")
    try:
        scheme, location = parse_address(address)
        get_backend(scheme)
        if scheme != "inproc":
            host, port = parse_host_port(location)
            if not host or not 0 < port < 65536:
                raise ValueError(f"host {host!r}, port {port} (1 to 65535)")
    except (ValueError, TypeError) as err:
        raise KinredundError(f"{address!r} is not a Dask scheduler address ({err}): {hint}") from err
    return address


def _ignore_sigint():
    """Ignore SIGINT while the local cluster starts (its worker processes are spawned meanwhile); return
    the handler to restore, or None (nothing changed) outside the main thread.

    A spawned process inherits an ignored signal and Python leaves it ignored, so a Ctrl-C at the
    terminal, sent to the whole process group, reaches only this process, which closes the cluster and
    names the sweep file kept, instead of every worker printing its own KeyboardInterrupt traceback
    (issue 26). The price: a Ctrl-C during the start itself (a few seconds) is ignored. (Blocking SIGINT
    instead, which would keep that Ctrl-C for later, does not reach the workers: they are started from
    the cluster's own threads, whose signal masks were measured to be clear.)
    """
    if threading.current_thread() is not threading.main_thread():
        return None
    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    return signal.SIG_DFL if old is None else old  # None: a handler set outside Python, restored as the default


def _restore_sigint(handler) -> None:
    if handler is not None:
        signal.signal(signal.SIGINT, handler)


@contextlib.contextmanager
def dask_client(client, scheduler: str | None, workers: int | None):
    """The client to run on: the caller's, one connected to ``scheduler``, or a new local cluster's."""
    if client is not None:
        yield client
        return
    from distributed import Client, LocalCluster

    if scheduler is not None:
        c = connect(scheduler)
        try:
            yield c
        finally:
            c.close()
        return
    # everything on the loopback interface; the scheduler's HTTP routes on a free port (no dashboard: no bokeh)
    handler = _ignore_sigint()
    try:
        cluster = LocalCluster(n_workers=workers or default_workers(), threads_per_worker=1, processes=True,
                               host="127.0.0.1", dashboard_address="127.0.0.1:0", silence_logs=logging.ERROR,
                               env=WORKER_ENV)
    except RuntimeError as err:  # a worker process did not start
        _restore_sigint(handler)
        raise KinredundError(
            f"the local Dask cluster did not start ({err}): its worker processes are spawned and import the "
            "main module, so a script must call sweep() under `if __name__ == '__main__':`") from err
    except BaseException:
        _restore_sigint(handler)
        raise
    try:
        _restore_sigint(handler)
        c = Client(cluster)
        try:
            c.run(ignore_interrupt)  # a terminal's Ctrl-C reaches the whole process group: this process decides
            yield c
        except BaseException:
            with _quiet_distributed():  # interrupted or failed: do not wait for the placements in flight
                _kill_workers(cluster)
                c.close()
                cluster.close()
            raise
        finally:
            c.close()
    finally:
        cluster.close()


@contextlib.contextmanager
def _quiet_distributed():
    """distributed's loggers in this process quiet while the killed cluster is closed, then as they were.

    The client's comms to the killed workers close under their batched sends, which distributed logs with a
    traceback (``distributed.batched``, INFO, CommClosedError) whenever a send was in flight: a Ctrl-C on a
    sweep printed a traceback on some runs (a race with the sends)."""
    names = ("distributed", "distributed.batched", "distributed.comm", "distributed.client", "distributed.core")
    loggers = [logging.getLogger(name) for name in names]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels, strict=True):
            lg.setLevel(level)


def connect(scheduler: str):
    """A client of the Dask scheduler at ``scheduler``, or KinredundError within about CONNECT_TIMEOUT s.

    distributed's own ``timeout`` bounds the connection, not Dask's handshake after it, so a server that
    accepts and stays silent (an HTTP server) held ``Client()`` for ever. A Dask scheduler sends its half
    of the handshake as soon as it accepts a connection: for a ``tcp://`` address that is checked first,
    on a plain socket with a deadline.
    """
    from distributed import Client
    from distributed.comm import parse_address, parse_host_port

    try:
        scheme, location = parse_address(scheduler)
        host, port = parse_host_port(location, 8786) if scheme == "tcp" else (None, None)
    except (ValueError, TypeError) as err:
        raise KinredundError(f"{scheduler!r} is not a Dask scheduler address (tcp://HOST:PORT): {err}") from err
    if scheme == "tcp":
        try:
            with socket.create_connection((host, port), timeout=CONNECT_TIMEOUT) as sock:
                sock.settimeout(CONNECT_TIMEOUT)
                answered = bool(sock.recv(1))
        except TimeoutError:
            answered = False
        except OSError as err:
            raise KinredundError(f"cannot reach the Dask scheduler at {scheduler!r}: {err}") from err
        if not answered:
            raise KinredundError(f"no Dask scheduler answered at {scheduler!r} within {CONNECT_TIMEOUT:.0f} s: "
                                 "something accepts connections there but does not speak Dask's protocol (a "
                                 "scheduler's address is tcp://HOST:PORT, port 8786 by default)")
    try:
        return Client(scheduler, timeout=f"{CONNECT_TIMEOUT}s")
    except (OSError, TimeoutError, ValueError, TypeError) as err:
        raise KinredundError(f"cannot reach the Dask scheduler at {scheduler!r}: {err}") from err


def ignore_interrupt() -> None:
    """Run on each worker of the local cluster: SIGINT ignored (the sweep's own process handles Ctrl-C)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _kill_workers(cluster) -> None:
    """End the worker processes of our own local cluster at once, by PID, without a restart.

    A nanny's close waits up to 4 s for its worker to finish the batch it runs (then kills it): Ctrl-C
    must return within a second. The nannies are told first that the workers are going
    (``close_gracefully``), so they do not start new ones.
    """
    import signal

    for nanny in list(cluster.workers.values()):
        with contextlib.suppress(Exception):
            nanny.close_gracefully()
            if nanny.pid:
                os.kill(nanny.pid, signal.SIGKILL)
