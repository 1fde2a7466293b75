"""The node's engine: the worker and explainer threads around the live pipeline.

The worker owns the pipeline (core/live/pipeline.py, the one bag replay runs): it loads the
compiled kernels, then applies the records the intake queued (keyframe estimates coalesce into
the newest, single poses are all kept), runs the jobs of services (~/check, ~/reset, a
retune's graph), takes one snapshot per burst that changed the map (the first stage; a burst
that did not only brings the snapshot's counts up to date) and publishes it with the newest
second-stage verdict. The explainer runs the second stage on the newest snapshot at most every
`explanation_period`, so a long explanation never delays an update. Both publish under the
engine's one lock; a verdict never replaces that of a newer snapshot (serials count them).
"""
from __future__ import annotations

import math
import os
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from typing import TYPE_CHECKING, Protocol

import numba

from map_consistency_ros.core.live import (GraphSnapshot, KeyframeEstimate, LivePipeline,
                                           LiveVerdict, PoseGraphNodes, UpdateSummary, warm_up)
from map_consistency_ros.ros.diagnostics import not_monitoring
from map_consistency_ros.core.configuration import NodeSettings

if TYPE_CHECKING:
    from map_consistency_ros.ros.intake import Intake

# The second stage's niceness (0 the default, 19 the lowest priority): an explanation may take
# as long as it likes, an update's latency is what the node promises.
EXPLAINER_NICENESS = 19
# The second stage's compiled kernels run on its own thread only: niceness alone does not keep
# it off the updates, whose kernels, split across the cores, wait for their slowest part
# (docs/node.md, Threads).
EXPLAINER_THREADS = 1


class EngineOutputs(Protocol):
    """What the engine publishes through (ros/outputs.py's Outputs): the engine knows it by
    this shape only, so that the outputs may import the engine and not the other way round.

    `timing` (seconds per stage of the last update) and `latency` (arrival of a change -> its
    verdict published) are the figures the engine fills in.
    """

    timing: dict[str, float]
    latency: float | None

    def publish(self, changed_at: float | None) -> None:
        """Publish the engine's snapshot with its newest verdict (under the engine's lock).

        Parameters
        ----------
        changed_at: the arrival (time.monotonic) of the input this answers; None for a new
            second stage.
        """

    def publish_diagnostics(self) -> None:
        """Publish /diagnostics."""

    def greet_marker_subscribers(self) -> None:
        """The whole marker array once more when a subscriber joined."""

    def clear_markers(self) -> None:
        """DELETEALL: the markers of a session that was reset go."""


class NotMonitoring(Exception):
    """The worker could not start (its compiled kernels failed to load)."""


class ShuttingDown(Exception):
    """A service gave up waiting because the node is shutting down."""


class ExplanationFailed(Exception):
    """The second stage raised: logged and shown in diagnostics, tried again a period later."""


def _run_kernels_on(threads: int) -> None:
    """Run the calling thread's compiled kernels on `threads` threads (0: every core numba
    has; more than it has: all of them). Thread-local: other threads keep theirs."""
    available = numba.config.NUMBA_NUM_THREADS
    numba.set_num_threads(available if threads == 0 else min(threads, available))


def _yield_to_updates() -> None:
    """Lower the calling thread's CPU priority (Linux: nice is per thread) and run its
    compiled kernels on it alone, so that on a loaded machine the second stage takes what the
    first-stage updates leave instead of slowing them down.

    Kernel threads first: the first call launches numba's threading layer, whose threads
    inherit the niceness of the thread that creates them (Linux), and must keep the node's.
    """
    _run_kernels_on(EXPLAINER_THREADS)
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), EXPLAINER_NICENESS)
    except (AttributeError, OSError):  # not Linux, or not allowed: same priority, still correct
        pass


class Engine:
    """The worker and explainer threads (see the module docstring).

    Parameters
    ----------
    pipeline: the live pipeline, owned by the worker from `start` on.
    settings: the node's settings.
    logger: the node's logger.
    wake: set when there is work: records queued, a job submitted, a stop.

    `snapshot` and `verdict` are what the outputs publish, replaced whole under `lock` (a
    reader without the lock reads each once).
    """

    def __init__(self, pipeline: LivePipeline, settings: NodeSettings, logger,
                 wake: threading.Event) -> None:
        self.pipeline = pipeline
        self._settings = settings
        self._logger = logger
        self._wake = wake
        # the worker and the explainer both publish (reentrant: a reset takes a snapshot)
        self.lock = threading.RLock()
        self._explain_wake = threading.Event()
        self._stop = threading.Event()
        self._ready = threading.Event()  # set once the worker has loaded the kernels
        self.start_failure = ''  # why loading the kernels failed: the worker never ran
        self.explanation_failure = ''  # why the last explanation failed, '' after a success
        self._explained_at = -math.inf  # time.monotonic of the last explanation's end
        self._jobs: deque[tuple[Callable[[], object], Future]] = deque()
        self.frame_id = settings.frame_id or 'map'
        self.snapshot = pipeline.evaluate()  # replaced whole by the worker
        self._serial = 0  # counts snapshots: a verdict never replaces one of a newer snapshot
        self.verdict: LiveVerdict | None = None  # the newest, on `snapshot` or an older one
        self._verdict_serial = -1
        self._intake: Intake | None = None
        self._outputs: EngineOutputs | None = None
        self._worker = threading.Thread(target=self._work, name='map_consistency_worker',
                                        daemon=True)
        self._explainer = threading.Thread(target=self._explain_loop,
                                           name='map_consistency_explainer', daemon=True)

    def start(self, intake: Intake, outputs: EngineOutputs) -> None:
        """Start both threads.

        Parameters
        ----------
        intake: the node's intake, whose queued records the worker takes.
        outputs: the node's outputs, which publish the results.
        """
        self._intake, self._outputs = intake, outputs
        self._worker.start()
        self._explainer.start()

    @property
    def ready(self) -> bool:
        """Whether the worker has loaded the compiled kernels."""
        return self._ready.is_set()

    @property
    def alive(self) -> bool:
        """Whether a thread is still running (an update cannot be interrupted)."""
        return self._worker.is_alive() or self._explainer.is_alive()

    def stop(self, timeout: float) -> None:
        """Stop both threads; waiting services give up.

        Parameters
        ----------
        timeout: seconds to wait for each thread at most; one still running then (an update
            cannot be interrupted) ends by itself, a daemon.
        """
        self.begin_stop()
        self._worker.join(timeout=timeout)
        self._explainer.join(timeout=timeout)

    def begin_stop(self) -> None:
        """Ask both threads to stop; waiting services give up at once."""
        self._stop.set()
        self._wake.set()

    # -- jobs of services ----------------------------------------------------------------------

    def run(self, job: Callable[[], object], timeout: float):
        """`job()` on the worker thread (the pipeline's owner), on every core.

        Parameters
        ----------
        job: a function of no argument; it may use the pipeline.
        timeout: seconds to wait for its result.

        Returns
        -------
        Its result; its exception is raised here. ShuttingDown when the node stops first,
        NotMonitoring when the worker could not start, TimeoutError after `timeout` seconds.
        """
        future: Future = Future()
        self._jobs.append((job, future))
        self._wake.set()
        return self.wait(future, timeout)

    def wait(self, future: Future, timeout: float):
        """Wait for a job's result.

        Parameters
        ----------
        future: the job's future.
        timeout: seconds to wait at most.

        Returns
        -------
        The future's result (its exception is raised here); ShuttingDown when the node stops
        first, NotMonitoring when the worker could not start, TimeoutError after `timeout`.
        """
        deadline = time.monotonic() + timeout
        while not self._stop.is_set():
            if self.start_failure:
                raise NotMonitoring(self.start_failure)
            try:
                return future.result(timeout=min(0.05, max(deadline - time.monotonic(), 0.0)))
            except FutureTimeout:
                if time.monotonic() >= deadline:
                    raise TimeoutError from None
        raise ShuttingDown

    def check(self) -> tuple[UpdateSummary, LiveVerdict | None]:
        """Measure every pair again, explain at once and publish (a job: worker thread).

        Returns
        -------
        The recomputation's summary and the verdict, None when there is no keyframe yet.
        ExplanationFailed when the second stage failed.
        """
        summary = self.pipeline.recompute()
        self._take_snapshot()
        if self.snapshot.result is None:
            return summary, None
        self._outputs.timing = {'monitor_s': summary.elapsed}
        self._publish_verdict(time.monotonic() - summary.elapsed, explain_now=True)
        return summary, self.verdict

    def reset(self, reason: str) -> int:
        """Forget every scan, keyframe and constraint and publish (a job: worker thread).

        Parameters
        ----------
        reason: why, for the log and the diagnostics' last reset.

        Returns
        -------
        The keyframes forgotten.
        """
        keyframes = self.pipeline.monitor.keyframe_count
        self.pipeline.reset(reason)
        self._after_reset(reason)  # takes the new snapshot
        self._outputs.publish_diagnostics()
        return keyframes

    # -- the worker ------------------------------------------------------------------------

    def _work(self) -> None:
        _run_kernels_on(self._settings.update_threads)
        # records queue meanwhile: the first update then finds the kernels loaded
        started = time.monotonic()
        try:
            warm_up()
        except Exception as error:  # noqa: BLE001 - the node stays up to say why it cannot work
            self.start_failure = f'{type(error).__name__}: {error}'
            self._logger.error(not_monitoring(self.start_failure))
            return
        self._logger.info(f'kernels ready in {time.monotonic() - started:.1f} s')
        self._ready.set()
        while not self._stop.is_set():
            self._wake.wait(timeout=0.5)
            self._wake.clear()
            try:
                self._work_once()
            except Exception as error:  # noqa: BLE001 - the worker must outlive any bug
                self._logger.error(f'monitor update failed: {error!r}')

    def _work_once(self) -> None:
        """Apply what arrived, answer queued jobs, publish the first stage's update."""
        changed_at = None  # arrival of the oldest record that changed the map
        records = self._intake.take()
        taken = time.monotonic()
        for arrival, record in records:
            summary, reset = self._apply(record)
            if summary is not None or reset:
                changed_at = arrival if changed_at is None else min(changed_at, arrival)
        applied_seconds = time.monotonic() - taken  # every record, changing the map or not
        while self._jobs:
            job, future = self._jobs.popleft()
            _run_kernels_on(0)  # a service caller waits for the job: every core
            try:
                future.set_result(job())
            except Exception as error:  # noqa: BLE001 - handed to the waiting service
                future.set_exception(error)
            finally:
                _run_kernels_on(self._settings.update_threads)
        self._outputs.greet_marker_subscribers()
        if changed_at is None:
            # no keyframe changed (scans waiting for their pose): a snapshot would copy every
            # keyframe again, for each such scan; only the counts move
            with self.lock:
                self.snapshot = self.pipeline.recount(self.snapshot)
        else:
            start = time.perf_counter()
            self._take_snapshot()
            self._outputs.timing = {'queued_s': max(taken - changed_at, 0.0),
                                    'monitor_s': applied_seconds,
                                    'snapshot_s': time.perf_counter() - start}
            try:
                self._publish_verdict(changed_at)
            except ExplanationFailed:
                pass  # no verdict yet: diagnostics say why, the explainer tries again
        if self._verdict_behind():
            self._explain_wake.set()

    def _apply(self, record) -> tuple[UpdateSummary | None, bool]:
        """Apply one record through the pipeline: (the update or None, whether it reset)."""
        if isinstance(record, (KeyframeEstimate, GraphSnapshot, PoseGraphNodes)):
            self.frame_id = self._settings.frame_id or record.frame_id or 'map'
        applied = self.pipeline.apply(record)
        self._intake.record_problems(record, applied.warnings)
        if applied.reset:
            self._after_reset(applied.reset)
        return applied.summary, bool(applied.reset)

    def _after_reset(self, reason: str) -> None:
        self._logger.warning(f'monitor reset: {reason}')
        with self.lock:
            self._take_snapshot()
            self.verdict, self._verdict_serial = None, self._serial
            self._outputs.clear_markers()
        self._intake.forget_losses()
        self._outputs.latency = None

    def _take_snapshot(self) -> None:
        """The pipeline's first stage becomes the snapshot published (worker thread)."""
        snapshot = self.pipeline.evaluate()
        with self.lock:
            self.snapshot, self._serial = snapshot, self._serial + 1

    # -- the second stage ------------------------------------------------------------------

    def _verdict_behind(self) -> bool:
        """Whether the last verdict judged an older snapshot than the current one."""
        return (self.snapshot.result is not None
                and (self.verdict is None
                     or self.verdict.snapshot.result is not self.snapshot.result))

    def _explain(self, snapshot) -> LiveVerdict:
        """Both stages' verdict on `snapshot` (any thread; the pipeline explains one at a
        time)."""
        try:
            verdict = self.pipeline.explain(snapshot)
        except Exception as error:  # noqa: BLE001 - any bug: the node says so and goes on
            self.explanation_failure = f'explanation failed: {type(error).__name__}: {error}'
            self._logger.error(self.explanation_failure)
            raise ExplanationFailed(self.explanation_failure) from error
        finally:
            self._explained_at = time.monotonic()  # a failure too: no retry in a tight loop
        self.explanation_failure = ''
        return verdict

    def _explain_loop(self) -> None:
        """The explainer thread: the second stage on the newest snapshot, at most every
        `explanation_period`, so a long explanation never delays a first-stage update."""
        _yield_to_updates()
        while not self._stop.is_set():
            wait = self._explained_at + self._settings.explanation_period - time.monotonic()
            if wait > 0.0:
                self._stop.wait(wait)
                continue
            if not self._verdict_behind():
                self._explain_wake.wait(timeout=0.5)
                self._explain_wake.clear()
                continue
            with self.lock:
                snapshot, serial = self.snapshot, self._serial
            try:
                verdict = self._explain(snapshot)
                with self.lock:
                    if serial > self._verdict_serial:  # not overtaken by ~/check or a reset
                        self.verdict, self._verdict_serial = verdict, serial
                        self._outputs.timing['explanation_s'] = verdict.seconds
                        self._outputs.publish(None)
            except ExplanationFailed:
                pass  # logged and shown in diagnostics; the next period tries again
            except Exception as error:  # noqa: BLE001 - the explainer must outlive any bug
                self._logger.error(f'explanation failed: {error!r}')

    def _publish_verdict(self, changed_at: float, explain_now: bool = False) -> None:
        """Markers, ~/consistent, ~/report and /diagnostics (worker thread) for a change whose
        input arrived at `changed_at` (time.monotonic): the first stage of the current snapshot
        with the newest second-stage verdict, which the explainer brings up to date.
        `explain_now`, or no verdict yet: the second stage first, on this thread."""
        snapshot = self.snapshot
        if snapshot.result is None:
            return
        if explain_now or self.verdict is None:
            serial = self._serial
            try:
                verdict = self._explain(snapshot)
            except ExplanationFailed:
                self._outputs.publish_diagnostics()  # no verdict to publish, or not the one asked
                raise
            with self.lock:
                self.verdict, self._verdict_serial = verdict, serial
                self._outputs.timing['explanation_s'] = verdict.seconds
        with self.lock:
            self._outputs.publish(changed_at)
