"""The Dask client that campaigns, studies and the benchmarks run their tasks on.

``local`` (the default) starts a :class:`dask.distributed.LocalCluster` of worker
processes, one thread each, bound to 127.0.0.1, with the dashboard off (or on
127.0.0.1 at a free port); an address (``tcp://HOST:PORT``) connects to a
scheduler users already run. Tasks receive paths and settings only, never
sources or arrays: each worker reads its own log or simulates its own run.

A worker that dies is replaced by its nanny and the scheduler runs its task
again elsewhere (up to ``distributed.scheduler.allowed-failures`` times); a
task that raises is run again ``RETRIES`` times (Dask's ``retries=``). Tasks
that catch the user's errors themselves (a corrupt log) return them as data,
so only the unexpected ones are retried.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import uuid
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, TypeVar

from ptinertia.errors import UsageError

T = TypeVar("T")

LOCAL = "local"
RETRIES = 2
# how long to wait for a remote scheduler to answer, and for its workers to join
CONNECT_TIMEOUT_S = 20.0
PROTOCOLS = ("tcp", "tls", "inproc", "ucx", "ws", "wss")


@dataclass(frozen=True)
class ClusterSpec:
    """Where tasks run: ``scheduler`` is ``"local"`` or an address, ``workers`` how many
    processes to start (local) or to wait for (address); ``dashboard`` serves Dask's
    dashboard on 127.0.0.1 (local only); ``connect_timeout_s`` bounds the wait for a
    remote scheduler and its workers."""

    scheduler: str = LOCAL
    workers: int | None = None
    dashboard: bool = False
    connect_timeout_s: float = CONNECT_TIMEOUT_S

    def __post_init__(self) -> None:
        if self.workers is not None and self.workers < 1:
            raise UsageError(f"--workers: expected a positive number, got {self.workers}")
        if self.scheduler != LOCAL:
            check_address(self.scheduler)


def check_address(address: str) -> None:
    """Raise :class:`UsageError` unless ``address`` reads ``PROTOCOL://HOST:PORT``."""
    protocol, sep, rest = address.partition("://")
    host, colon, port = rest.rpartition(":")
    if not sep or protocol not in PROTOCOLS or not colon or not host or not port.isdigit():
        raise UsageError(
            f"--scheduler: expected 'local' or an address like tcp://127.0.0.1:8786, got {address!r}"
        )


def add_cluster_arguments(p: argparse.ArgumentParser) -> None:
    """``--scheduler``, ``--workers`` and ``--dashboard`` (shared by replay and study)."""
    p.add_argument(
        "--scheduler",
        default=LOCAL,
        metavar="ADDR",
        help="local (default: a cluster of worker processes on this machine) or the address "
        "of a running Dask scheduler, e.g. tcp://10.0.0.5:8786",
    )
    p.add_argument(
        "--workers",
        type=int,
        metavar="N",
        help="worker processes to start (local; default: one per core), or to wait for (address)",
    )
    p.add_argument(
        "--dashboard",
        action="store_true",
        help="serve Dask's dashboard on 127.0.0.1 (local cluster; its port is printed)",
    )


def spec_from_args(args: argparse.Namespace) -> ClusterSpec:
    return ClusterSpec(args.scheduler, args.workers, bool(getattr(args, "dashboard", False)))


def default_workers() -> int:
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else 1)


@contextmanager
def open_client(spec: ClusterSpec) -> Iterator[Any]:
    """A connected :class:`dask.distributed.Client`; a local cluster is shut down on exit."""
    # imported here: dask takes about a second to import, and only these commands need it
    from dask.distributed import Client, LocalCluster

    if spec.scheduler == LOCAL:
        cluster = LocalCluster(
            n_workers=spec.workers or default_workers(),
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address="127.0.0.1:0" if spec.dashboard else None,
            # Dask's own log lines (a heartbeat cut at shutdown) would bury ours
            silence_logs=logging.CRITICAL,
        )
        try:
            with Client(cluster) as client:
                if spec.dashboard:
                    print(f"dask dashboard: {client.dashboard_link}", file=sys.stderr)
                yield client
        finally:
            cluster.close()
        return
    try:
        client = Client(spec.scheduler, timeout=spec.connect_timeout_s)
    except (OSError, TimeoutError) as err:
        raise UsageError(f"--scheduler: cannot reach {spec.scheduler} ({err})") from None
    try:
        try:
            client.wait_for_workers(spec.workers or 1, timeout=spec.connect_timeout_s)
        except TimeoutError:
            raise UsageError(
                f"--scheduler: {spec.scheduler} has fewer than {spec.workers or 1} workers "
                f"after {spec.connect_timeout_s:g} s"
            ) from None
        yield client
    finally:
        client.close()


def run_tasks(
    client: Any,
    fn: Callable[..., T],
    calls: Sequence[tuple[Any, ...]],
    on_done: Callable[[int, Any], None] | None = None,
    key: str = "ptinertia",
) -> list[T | BaseException]:
    """``fn(*call)`` for every call on the cluster, results in the order of ``calls``.

    A call whose task still fails after the retries (or whose worker died too often)
    gives its exception in its place, so the others complete. ``on_done(i, result)`` is
    called as each finishes, in any order (the progress bar, writing results as they come).
    """
    from dask.distributed import as_completed

    # unique keys: other clients may share a remote scheduler
    token = uuid.uuid4().hex[:8]
    futures = [
        client.submit(fn, *call, key=f"{key}-{token}-{i}", retries=RETRIES, pure=False)
        for i, call in enumerate(calls)
    ]
    index = {f.key: i for i, f in enumerate(futures)}
    out: list[Any] = [None] * len(futures)
    for future in as_completed(futures):
        i = index[future.key]
        try:
            out[i] = future.result()
        except Exception as err:  # a bug or a dead worker: one row
            out[i] = err
        if on_done is not None:
            on_done(i, out[i])
    return out


def failure_line(err: BaseException) -> str:
    """One line for a task that failed on every try (a bug, or workers that kept dying)."""
    text = str(err).strip().splitlines()
    return f"{type(err).__name__}: {text[0] if text else 'no message'}"


def map_on_cluster(
    spec: ClusterSpec, fn: Callable[..., T], calls: Sequence[tuple[Any, ...]]
) -> list[T]:
    """``[fn(*call) for call in calls]`` on a cluster, raising the first failure (benchmarks)."""
    with open_client(spec) as client:
        results = run_tasks(client, fn, calls)
    for r in results:
        if isinstance(r, BaseException):
            raise r
    return results  # type: ignore[return-value]
