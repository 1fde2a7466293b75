"""One runner for the commands that judge many maps (`batch`, `evaluate`): `function(item,
*arguments)` for every item, in this process, in a local process pool, or on a Dask
distributed cluster.

Every job in a pool or on a cluster runs numba single-threaded: the jobs themselves already
occupy the cores (one process per core locally; one thread per worker process on a cluster,
see docs/batch.md). In this process (one worker) numba keeps all its threads.

A worker process that dies (killed, out of memory, a crash in compiled code) takes only its
own item: the item comes back as a `WorkerDied` and the other items are still judged. In the
local pool at most `workers` items are in flight, so a broken pool names at most that many
suspects; each suspect is then run alone, which tells the item that kills its worker from the
ones that only shared the pool with it. Dask tells them apart itself (a task on a worker
that dies is retried elsewhere and given up after `distributed.scheduler.allowed-failures`).
"""
from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any

from map_consistency_ros.io.errors import InputError

Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class WorkerDied:
    """The result of an item whose worker process ended before returning it."""

    message: str


def run_all(function: Callable, items: Sequence, arguments: tuple = (),
            workers: int | None = None, scheduler: str | None = None,
            progress: Progress | None = None) -> list:
    """function(item, *arguments) for every item; results in the order of `items`.

    Parameters
    ----------
    function: the job; picklable (defined at module level) unless it runs in this process.
    items: one job each.
    arguments: the further arguments of every call.
    workers: local processes; None: one per core; 1: in this process. Not used with a
        `scheduler`.
    scheduler: the address of a Dask scheduler (tcp://host:8786); the workers must be able
        to import this package and read whatever the items name. None: run locally.
    progress: progress(done, total), called as items finish.

    Returns
    -------
    The result of every item, in the order of `items`; an item whose worker died yields
    `WorkerDied`. An exception raised by `function` propagates (after the pool is shut
    down); InputError for fewer than 1 worker or a scheduler that cannot be reached.
    """
    if scheduler is not None:
        return _on_dask(function, items, arguments, scheduler, progress)
    workers = workers or os.cpu_count() or 1
    if workers < 1:
        raise InputError('options', f'workers must be at least 1, got {workers}')
    if workers == 1:
        results = []
        for item in items:
            results.append(function(item, *arguments))
            if progress:
                progress(len(results), len(items))
        return results
    return _local_pool(function, items, arguments, workers, progress)


def single_threaded_call(function: Callable, item: Any, *arguments) -> Any:
    """function(item, *arguments) with numba on one thread (the module docstring says why).

    Parameters
    ----------
    function: the job.
    item: its item.
    arguments: its further arguments.

    Returns
    -------
    What `function` returns.
    """
    import numba
    numba.set_num_threads(1)  # numba's setting is per calling thread: set it in the job
    return function(item, *arguments)


def _pool(workers: int) -> ProcessPoolExecutor:
    # spawned, not forked: numba's thread pool in this process does not survive a fork
    return ProcessPoolExecutor(max_workers=workers,
                               mp_context=multiprocessing.get_context('spawn'))


def _local_pool(function: Callable, items: Sequence, arguments: tuple, workers: int,
                progress: Progress | None) -> list:
    results: list = [None] * len(items)
    waiting = list(range(len(items)))[::-1]  # popped from the end: item order
    suspects: list[int] = []
    done = 0

    def finish(index: int, value: Any) -> None:
        nonlocal done
        results[index] = value
        done += 1
        if progress:
            progress(done, len(items))

    while waiting:
        with _pool(workers) as pool:
            running: dict = {}
            while waiting or running:
                while waiting and len(running) < workers:
                    index = waiting.pop()
                    running[pool.submit(single_threaded_call, function, items[index],
                                        *arguments)] = index
                finished, _ = wait(running, return_when=FIRST_COMPLETED)
                broken = False
                for future in finished:
                    index = running.pop(future)
                    try:
                        finish(index, future.result())
                    except BrokenProcessPool:
                        suspects.append(index)
                        broken = True
                if broken:
                    # every item still running broke with the pool; they are all suspects
                    suspects.extend(running.values())
                    for future in running:
                        future.cancel()
                    break
        for index in suspects:
            finish(index, _alone(function, items[index], arguments, len(suspects) == 1))
        suspects = []
    return results


def _alone(function: Callable, item: Any, arguments: tuple, known: bool) -> Any:
    """The item's result from a pool of its own, or WorkerDied (`known`: it was the only item
    in the broken pool, so it need not run again)."""
    message = 'the worker process ended before returning a result'
    if known:
        return WorkerDied(message)
    with _pool(1) as pool:
        try:
            return pool.submit(single_threaded_call, function, item, *arguments).result()
        except BrokenProcessPool:
            return WorkerDied(message)


def _on_dask(function: Callable, items: Sequence, arguments: tuple, scheduler: str,
             progress: Progress | None) -> list:
    try:
        from distributed import Client, as_completed
        from distributed.scheduler import KilledWorker
    except ImportError:
        raise InputError('--scheduler', "needs dask.distributed: pip install "
                                        "'map_consistency_ros[distributed]'") from None
    results: list = [None] * len(items)
    try:
        client = Client(scheduler)
    except (OSError, ValueError) as error:  # nothing answers (a timeout is an OSError), or
        # the address is malformed
        raise InputError(f'--scheduler {scheduler}', str(error)) from None
    with client:
        futures = {client.submit(single_threaded_call, function, item, *arguments,
                                 pure=False): index for index, item in enumerate(items)}
        for done, future in enumerate(as_completed(futures), start=1):
            try:
                results[futures[future]] = future.result()
            except KilledWorker as error:
                results[futures[future]] = WorkerDied(f'the Dask workers running it died '
                                                      f'({error})')
            if progress:
                progress(done, len(items))
    return results
