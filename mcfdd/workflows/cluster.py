"""Campaign chunks on Dask distributed (the ``distributed`` extra): local cluster, existing scheduler, worker set-up.

Dask runs the chunk tasks (:func:`mcfdd.workflows.campaign.run_chunk`) with its own retries: a
task whose worker dies is run again elsewhere, and the driver writes each part as its result
arrives, so the table is the same as in one process (tables do not depend on the device count,
the chunk or the process). A Dask scheduler runs whatever task it is sent, so the local cluster
listens on 127.0.0.1 only, a remote one should be reached over ``tls://``, and plain ``tcp://``
to another host gives a warning.
"""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import os
import socket
import ssl
import warnings
from pathlib import Path

from distributed import Client, LocalCluster, as_completed
from distributed.comm.addressing import get_address_host, parse_address, parse_host_port
from distributed.diagnostics.plugin import WorkerPlugin
from distributed.security import Security

from mcfdd import devices
from mcfdd.progress import note
from mcfdd.workflows import resources
from mcfdd.workflows.common import ResourceError, compile_cache

SCHEMES = ("tcp", "tls")
PLUGIN = "mcfdd-worker-setup"


class ClusterError(ResourceError):
    """A cluster that cannot be used: a bad address, an unreachable scheduler, no workers, bad TLS files."""


def _is_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(socket.gethostbyname(host)).is_loopback
    except (OSError, ValueError):
        return False


def check_address(address: str) -> str:
    """``address`` if it is ``tcp://HOST:PORT`` or ``tls://HOST:PORT``; a warning for plain tcp to another host."""
    try:
        scheme, location = parse_address(address, strict=True)
        host, port = parse_host_port(location)
    except (ValueError, TypeError):
        scheme = host = port = None
    if scheme not in SCHEMES or not host or not port:
        raise ClusterError(f"--scheduler: {address!r} is not an address like tls://HOST:PORT or tcp://127.0.0.1:PORT")
    if scheme == "tcp" and not _is_loopback(host):
        warnings.warn(f"scheduler {address}: plain tcp:// to another host; anyone who reaches the scheduler can run "
                      f"code on its workers: use tls:// or keep the cluster inside a trusted network (README, Beyond "
                      f"one machine)", stacklevel=3)
    return address


def security(tls_ca_file=None, tls_cert=None, tls_key=None):
    """Dask ``Security`` from TLS files (all three, like ``dask worker``'s flags), else Dask's own configuration."""
    files = {"tls_ca_file": tls_ca_file, "tls_cert": tls_cert, "tls_key": tls_key}
    given = {k: v for k, v in files.items() if v is not None}
    if not given:
        return Security()
    if len(given) < len(files):
        missing = [f"--{k.replace('_', '-')}" for k in files if k not in given]
        raise ClusterError(f"{missing[0]}: missing ({', '.join(missing)}); give the CA file, the certificate and its "
                           f"key together")
    for key, path in given.items():
        if not Path(path).is_file():
            raise ClusterError(f"--{key.replace('_', '-')}: {path} is not a file")
    return Security(tls_ca_file=tls_ca_file, tls_client_cert=tls_cert, tls_client_key=tls_key,
                    require_encryption=True)


@contextlib.contextmanager
def dask_cluster(scheduler: str | None = None, workers: int | None = None, security=None, timeout_s: float = 10.0):
    """A Dask client to pass as ``run_campaign(..., executor=client)``, closed on exit.

    Args:
        scheduler: address of a running scheduler (``tls://HOST:PORT``; ``tcp://`` on a trusted
            network), or None for a local cluster.
        workers: the local cluster's number of worker processes (one thread each, listening on
            127.0.0.1 only), or None with ``scheduler``.
        security: a ``distributed.Security`` (:func:`security`) for the scheduler; None: Dask's
            configuration.
        timeout_s: how long to try to reach the scheduler, and then to wait for a first worker.

    Raises:
        ClusterError: a bad address, an unreachable scheduler or one without workers, within
            ``timeout_s``.
    """
    if (scheduler is None) == (workers is None):
        raise ClusterError("--scheduler/--workers: give either a scheduler address or a number of local workers")
    if workers is not None:
        resources.check_workers(workers)
        # The workers would inherit this process's device count; each gets its share of the cores instead.
        env = {"XLA_FLAGS": devices.xla_flags(local_devices(workers))}
        note(f"campaign: starting a local Dask cluster of {workers} worker process(es)", True)
        # Worker logs silenced up to CRITICAL: a task's error reaches the client as its exception, and an
        # interrupt that closes the scheduler under a worker's heartbeat made the worker log a traceback.
        with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                          dashboard_address=None, silence_logs=logging.CRITICAL, env=env) as local, \
                Client(local) as client:
            try:
                yield client
            except KeyboardInterrupt:  # closed at once, without the logs of the connections and messages it cuts
                for name in ("distributed", "asyncio"):
                    logging.getLogger(name).setLevel(logging.CRITICAL)
                raise
        return
    address = check_address(scheduler)
    try:
        client = Client(address, security=security, timeout=timeout_s)
    except TypeError:  # Dask's words for a tls:// address without TLS settings
        raise ClusterError(f"--scheduler: {address} is a tls:// address but no TLS settings are given; give "
                           f"--tls-ca-file, --tls-cert and --tls-key (or Dask's distributed.comm.tls "
                           f"configuration)") from None
    except ssl.SSLError as err:
        raise ClusterError(f"--tls-ca-file/--tls-cert/--tls-key: the TLS set-up for {address} failed: "
                           f"{err.reason or err}") from None
    except (OSError, TimeoutError, ValueError) as err:
        raise ClusterError(f"--scheduler: cannot reach {address} within {timeout_s:g} s ({err})") from None
    with client:
        try:
            client.wait_for_workers(1, timeout=timeout_s)
        except TimeoutError:
            raise ClusterError(f"--scheduler: {address} has no workers after {timeout_s:g} s") from None
        yield client


def local_devices(threads: int) -> int:
    """JAX devices of each process when ``threads`` worker threads share this host's cores
    (:data:`mcfdd.devices.DEVICES_PER_CORE` per core of its share)."""
    return devices.DEVICES_PER_CORE * max(1, (os.cpu_count() or 1) // max(threads, 1))


class WorkerSetup(WorkerPlugin):
    """Set-up of each worker process before its first chunk: its share of the host's cores, the compile cache.

    Args:
        cache: the compile-cache folder (:func:`mcfdd.workflows.common.compile_cache`; None is
            the worker's own user cache folder, 'off' none).
        host_threads: threads of all the cluster's workers per host; a worker gets
            DEVICES_PER_CORE x (cores // threads) JAX devices.
    """

    def __init__(self, cache, host_threads: dict):
        self.cache, self.host_threads = cache, dict(host_threads)

    def setup(self, worker):
        threads = self.host_threads.get(get_address_host(worker.address), worker.state.nthreads)
        devices.use_cores(local_devices(threads))
        compile_cache(self.cache)


def worker_memory(client) -> float | None:
    """The smallest memory limit (bytes) of the client's workers, or None when none is set."""
    limits = [info.get("memory_limit") or 0 for info in client.scheduler_info(n_workers=-1)["workers"].values()]
    return float(min(limits)) if limits and min(limits) > 0 else None


def _host_threads(client) -> dict:
    threads: dict = {}
    for info in client.scheduler_info(n_workers=-1)["workers"].values():
        threads[info["host"]] = threads.get(info["host"], 0) + info["nthreads"]
    return threads


def set_up(client, cache) -> None:
    """Set up each worker of ``client`` before its first task, and those that join later (:class:`WorkerSetup`)."""
    client.register_plugin(WorkerSetup(cache, _host_threads(client)), name=PLUGIN)


def submit(client, task, cfg, chunks, size: int, plan, cache):
    """Chunks of a campaign as tasks of ``client``: (results in completion order, cancel function).

    The workers are set up first (:class:`WorkerSetup`, also on workers that join later); the
    config and the design plan are sent once to every worker, each task carries only its ids.
    A task whose worker dies is rescheduled by Dask; one that raises is retried twice.
    """
    set_up(client, cache)
    shared_cfg, shared_plan = client.scatter([cfg, plan], broadcast=True, hash=False)
    futures = {client.submit(task, shared_cfg, ids, size, shared_plan, pure=False, retries=2): ids for ids in chunks}

    def results():
        for future in as_completed(futures):
            yield futures[future], *future.result()

    return results(), lambda: client.cancel(list(futures))
