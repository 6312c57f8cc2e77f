"""Identify a fleet's records with Dask: every chunk of a directory of record files
(``fleet.sources``) identified by a worker (``fleet.work``) and written as a part of one Parquet
table; a local cluster by default, any Dask cluster by its scheduler's address.

Nothing is lost: a part is written atomically when its chunk is done, a run given the same
output skips the chunks whose parts exist (a killed run resumes where it stopped), a task on a
worker that dies is run again on another (Dask's own rescheduling, and ``retries``), and a
record that cannot be identified gets its row with the reason.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from aeid_struct.fleet.sources import chunks
from aeid_struct.fleet.work import identify_chunk, part_path

__all__ = ["CONNECT_TIMEOUT", "FleetRun", "identify_many"]

#: How long a scheduler given by its address may take to answer.
CONNECT_TIMEOUT = "30s"


@dataclass(frozen=True)
class FleetRun:
    """What :func:`identify_many` did.

    Attributes
    ----------
    out : Path
        The table: a directory of Parquet parts (``pandas.read_parquet(out)`` reads it whole).
    chunks : int
        Chunks in the source.
    skipped : int
        Those whose parts an earlier run had written.
    records : int
        Records identified in this run.
    ok : int
        Those of them with a model.
    seconds : float
        Wall time of this run, the cluster's start included.
    workers : int
    """

    out: Path
    chunks: int
    skipped: int
    records: int
    ok: int
    seconds: float
    workers: int

    @property
    def records_per_second(self) -> float:
        return self.records / self.seconds if self.seconds > 0 else float("nan")


def _client(scheduler: str | None, workers: int | None):
    """``(client, cluster, owned)``: the process's client of ``scheduler`` where it has one
    (a second client of one scheduler in a process binds futures to another event loop), else
    a new one; a new local cluster where no scheduler is given. Only what is owned is closed."""
    from dask.distributed import Client, LocalCluster, default_client

    if scheduler is not None:
        try:
            current = default_client()
        except ValueError:          # no client in this process
            current = None
        if current is not None and current.scheduler.address == scheduler:
            return current, None, False
        try:
            return Client(scheduler, timeout=CONNECT_TIMEOUT), None, True
        except OSError as err:
            raise ValueError(f"scheduler {scheduler!r}: no Dask scheduler answered ({err})") \
                from None
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                           dashboard_address=None)
    return Client(cluster), cluster, True


def identify_many(source, identifier: str, out, *, scheduler: str | None = None,
                  workers: int | None = None, chunk: int = 10_000, retries: int = 2,
                  progress=print, maps: dict | None = None) -> FleetRun:
    """Identify every record under ``source`` with a trained identifier, on Dask.

    Parameters
    ----------
    source : str or PathLike
        A directory of record files (searched recursively) or one file
        (``fleet.sources``: ``.npy``, ``.npz``, ``.parquet``, ``.csv``).
    identifier : str
        A shipped identifier's name or an identifier file, read once per worker.
    out : str or PathLike
        The output directory (created): one Parquet part per chunk, the table of
        ``fleet.work``.
    scheduler : str, optional
        A Dask scheduler's address (``tcp://host:8786``); None starts a local cluster of
        ``workers`` processes (one thread each), closed at the end.
    workers : int, optional
        Local workers (default: Dask's, one per core).
    chunk : int, >= 1
        Records per task at most.
    retries : int, >= 0
        Times a failed task is run again.
    progress : callable or None
        Called with a line as chunks finish.
    maps : dict str -> casadi.Function, optional
        The user maps an identifier file of one's own mechanism names (``aeid_struct.load``'s
        ``maps=``), sent to every worker and checked there against the file's SHA-256.

    Returns
    -------
    FleetRun

    Raises
    ------
    ValueError
        Naming the argument: a source without record files, an identifier that is not a
        shipped name or a readable file, a bad chunk, workers or retries, an ``out`` that is a
        file, a scheduler that does not answer.
    """
    from aeid_struct.loading import load

    start = time.perf_counter()
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)
                                or workers < 1):
        raise ValueError(f"workers must be an integer >= 1 or None; got {workers!r}")
    if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
        raise ValueError(f"retries must be an integer >= 0; got {retries!r}")
    ident = load(identifier, maps=maps)      # refused here, by name, not on every worker
    if not hasattr(ident, "steps"):
        raise ValueError(f"identifier {identifier!r} identifies one record at a time with a "
                         f"sample time of its own (a generic identifier); identify_many runs "
                         f"trained identifiers, whose records share their steps and dt")
    todo = chunks(source, chunk)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"out must be a directory (the table's parts); {str(out)!r} is a file")
    out.mkdir(parents=True, exist_ok=True)
    pending = [c for c in todo if not part_path(out, c).exists()]
    records = ok = 0
    client, cluster, owned = _client(scheduler, workers) if pending else (None, None, False)
    try:
        if pending:
            from dask.distributed import as_completed

            root = str(Path(source))
            futures = client.map(identify_chunk, [identifier] * len(pending), pending,
                                 [str(out)] * len(pending), [root] * len(pending),
                                 [maps] * len(pending),
                                 key=[f"aeid-chunk-{c.key}" for c in pending],
                                 retries=retries, pure=False)
            for done, future in enumerate(as_completed(futures), 1):
                result = future.result()
                records, ok = records + result["records"], ok + result["ok"]
                if progress is not None:
                    rate = records / (time.perf_counter() - start)
                    progress(f"chunk {done}/{len(pending)} ({result['key']}): "
                             f"{records} records, {rate:.0f} records/s")
        nworkers = len(client.scheduler_info()["workers"]) if client is not None else 0
    finally:
        if client is not None and owned:
            client.close()
        if cluster is not None:
            cluster.close()
    return FleetRun(out, len(todo), len(todo) - len(pending), records, ok,
                    time.perf_counter() - start, nworkers)
