"""The node's services (std_srvs/Trigger): ~/check, ~/retune_dcs, ~/reset (docs/node.md,
Services).

They run on a host node of their own, spun by a multi-threaded executor: a service waits for
the worker (a retune for minutes), so it needs a thread of its own, which the events executor
that takes the messages cannot give. ~/check and ~/reset are jobs on the worker, the pipeline's
owner; a retune takes the graph there and searches on a thread of its own, while monitoring
goes on. On shutdown every waiting call answers at once with a failure.
"""
from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future

from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from std_srvs.srv import Trigger

from map_consistency_ros.core.backend import TuningSettings, search_findings
from map_consistency_ros.ros.diagnostics import not_monitoring
from map_consistency_ros.ros.engine import Engine, ExplanationFailed, NotMonitoring, ShuttingDown
from map_consistency_ros.ros.outputs import Outputs
from map_consistency_ros.core.configuration import NodeSettings

SHUTTING_DOWN = 'the node is shutting down'


class Services:
    """The node's services on their host node (see the module docstring).

    Parameters
    ----------
    node: the node whose names the services take (e.g. /map_consistency/check).
    engine: the worker that runs the jobs.
    outputs: where a retune's result goes.
    tuning: the Phi search's settings; a retune (LivePipeline.retune) tests its map with the
        statistical test's parameters the engine's monitor runs with.
    settings: the node's settings.
    """

    def __init__(self, node: Node, engine: Engine, outputs: Outputs, tuning: TuningSettings,
                 settings: NodeSettings) -> None:
        self._engine = engine
        self._outputs = outputs
        self._tuning = tuning
        self._settings = settings
        self._lock = threading.Lock()
        self._calls = 0  # service calls being answered, for the shutdown to wait for
        self._retuning = threading.Lock()
        self._tuner: threading.Thread | None = None
        # The host ignores the command line (a `__node:=` rename would give it this node's
        # name too) and offers the services under this node's resolved names.
        self.host = Node(f'{node.get_name()}_services', namespace=node.get_namespace(),
                         context=node.context, use_global_arguments=False,
                         start_parameter_services=False)
        group = ReentrantCallbackGroup()
        for name, callback in (('~/check', self._on_check), ('~/retune_dcs', self._on_retune),
                               ('~/reset', self._on_reset)):
            self.host.create_service(Trigger, node.resolve_service_name(name), callback,
                                     callback_group=group)

    @property
    def answering(self) -> bool:
        """Whether service calls are still being answered."""
        with self._lock:
            return self._calls > 0

    @property
    def tuning(self) -> bool:
        """Whether a retune's search is still running (it cannot be interrupted)."""
        return self._tuner is not None and self._tuner.is_alive()

    def _answer(self, response: Trigger.Response, work: Callable[[], tuple[bool, str]]
                ) -> Trigger.Response:
        with self._lock:
            self._calls += 1
        try:
            response.success, response.message = work()
        except TimeoutError:
            response.success, response.message = False, 'timed out waiting for the monitor'
        except ShuttingDown:
            response.success, response.message = False, SHUTTING_DOWN
        except NotMonitoring as failure:
            response.success, response.message = False, not_monitoring(str(failure))
        finally:
            with self._lock:
                self._calls -= 1
        return response

    def _check(self) -> tuple[bool, str]:
        try:
            summary, verdict = self._engine.run(self._engine.check,
                                                self._settings.service_timeout)
        except ExplanationFailed as error:
            return False, f'no verdict: {error}'
        if verdict is None:
            return False, 'no keyframes yet: no trajectory pose matches a scan'
        result = verdict.snapshot.result
        return True, (f'{verdict.assessment.summary_line()}; the paper\'s test: '
                      f'{int(result.inconsistent.sum())} of {result.scan_count} scans fail, '
                      f'{result.failed_pair_count} of {result.tested_pair_count} tested pairs '
                      f'fail; {summary.measured_pairs} pairs measured in {summary.elapsed:.2f} s')

    def _on_check(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """~/check: recompute everything now and answer with the verdict."""
        return self._answer(response, self._check)

    def _reset(self) -> tuple[bool, str]:
        keyframes = self._engine.run(lambda: self._engine.reset('~/reset service'),
                                     self._settings.service_timeout)
        return True, f'reset: {keyframes} keyframes forgotten'

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """~/reset: forget every scan, keyframe and constraint (a new SLAM session)."""
        return self._answer(response, self._reset)

    def _on_retune(self, request: Trigger.Request,
                   response: Trigger.Response) -> Trigger.Response:
        """~/retune_dcs: the Phi search on the current graph while monitoring goes on."""
        if not self._retuning.acquire(blocking=False):
            response.success, response.message = False, 'a retune is already running'
            return response
        try:
            return self._answer(response, self._retune)
        except ValueError as error:
            response.success, response.message = False, f'retune failed: {error}'
            return response
        finally:
            self._retuning.release()

    def _retune(self) -> tuple[bool, str]:
        pipeline = self._engine.pipeline
        graph = self._engine.run(pipeline.slam_graph, self._settings.service_timeout)
        if graph is None:
            return False, ('no pose graph to tune: it needs constraint rows on the constraints '
                           'topic between trajectory poses, two of them keyframes')
        problem = pipeline.tuning_problem(graph)
        if problem:
            return False, f'cannot tune this graph honestly: {problem}'
        start = time.monotonic()
        future: Future = Future()

        def tune() -> None:
            try:
                future.set_result(pipeline.retune(graph, self._tuning))
            except Exception as error:  # noqa: BLE001 - handed to the waiting service
                future.set_exception(error)

        # a thread of its own: on shutdown the service answers at once and the search is
        # abandoned (it cannot be interrupted)
        self._tuner = threading.Thread(target=tune, name='map_consistency_retune', daemon=True)
        self._tuner.start()
        retune = self._engine.wait(future, math.inf)
        elapsed = time.monotonic() - start
        result = retune.tuning
        self._outputs.publish_tuning(result.phi, graph.stamps, result.poses)
        outside = (f'; {graph.keyframes_outside} keyframes named by no constraint left out'
                   if graph.keyframes_outside else '')
        # what tune warns about, named by the node's parameters
        findings = ''.join(f'; warning: {finding}'
                           for finding in search_findings(result, self._tuning))
        return True, (f'Phi* = {result.phi:.6g} (M = {result.average_inconsistency:.4g} m): '
                      f'optimized map {retune.assessment.summary_line()}; '
                      f'{graph.graph.vertex_count} poses, {graph.graph.edge_count} edges, '
                      f'{result.profile_phi.size} Phi values in {elapsed:.1f} s{outside}'
                      f'{findings}')
