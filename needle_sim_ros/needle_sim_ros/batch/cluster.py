"""The Dask client of a batch: a LocalCluster of worker processes (one thread each) by default, or an existing
scheduler (``--scheduler tcp://host:8786``, e.g. of a dask-jobqueue SLURM cluster), and results with a progress bar.
"""
from __future__ import annotations

import logging
import os
from contextlib import contextmanager
from typing import Any, Callable, Iterator, Sequence

from tqdm import tqdm


def default_workers() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


@contextmanager
def open_client(workers: int | None = None, scheduler: str | None = None) -> Iterator[Any]:
    """A ``distributed.Client``: connected to ``scheduler`` or to a new LocalCluster of ``workers`` processes (whose
    heartbeat failure at shutdown is not logged: :mod:`needle_sim_ros.batch.worker_logging`)."""
    from distributed import Client, LocalCluster

    from needle_sim_ros.batch.worker_logging import QuietShutdownHeartbeat
    if scheduler:
        with Client(scheduler) as client:
            yield client
        return
    with LocalCluster(n_workers=workers or default_workers(), threads_per_worker=1, processes=True,
                      dashboard_address=":0", silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        client.register_plugin(QuietShutdownHeartbeat())
        yield client


def map_ordered(client: Any, function: Callable, items: Sequence[Any], *args: Any, desc: str = "",
                quiet: bool = False, on_result: Callable[[int, Any], None] | None = None,
                on_error: Callable[[Any, BaseException], Any] | None = None) -> list[Any]:
    """``function(item, *args)`` for every item on the cluster; results in item order, a tqdm bar as they finish.
    ``on_result(index, result)`` is called on the client as each finishes (e.g. to save progress); a task that
    raises (or whose worker died) gives ``on_error(item, error)`` if given, else the error propagates."""
    from distributed import as_completed
    futures = [client.submit(function, item, *args, pure=False) for item in items]
    index = {future.key: i for i, future in enumerate(futures)}
    results: list[Any] = [None] * len(futures)
    with tqdm(total=len(futures), desc=desc, unit="task", disable=quiet) as bar:
        for future in as_completed(futures):
            i = index[future.key]
            try:
                results[i] = future.result()
            except Exception as error:  # noqa: BLE001 - e.g. distributed.KilledWorker
                if on_error is None:
                    raise
                results[i] = on_error(items[i], error)
            if on_result is not None:
                on_result(i, results[i])
            bar.update(1)
    return results
