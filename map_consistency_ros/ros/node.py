"""The live map-consistency node: scans and the SLAM poses in; verdict, markers, diagnostics out.

The node class only wires its parts: the intake (ros/intake.py: subscriptions that convert
messages into core records and queue them), the engine (ros/engine.py: the worker that applies
the records to the live pipeline shared with bag replay, core/live/pipeline.py, and the
explainer of the second stage), the outputs (ros/outputs.py: markers, verdict, report,
diagnostics) and the services (ros/services.py, on a host node of their own). The contract is
in docs/node.md.
"""
from __future__ import annotations

import os
import signal
import sys
import threading
import time

import rclpy
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import ParameterException
from rclpy.executors import Executor, ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from map_consistency_ros.core.configuration import (PARAMETERS, Configuration, ExecutorKind,
                                                    NodeSettings, unknown_parameters)
from map_consistency_ros.core.live import LivePipeline
from map_consistency_ros.core.parameters import ParameterSpec
from map_consistency_ros.ros import slam_toolbox_graph
from map_consistency_ros.ros.engine import Engine
from map_consistency_ros.ros.intake import Intake
from map_consistency_ros.ros.outputs import Outputs
from map_consistency_ros.ros.services import Services

# Parameters every rclpy node has, and per-topic QoS overrides: not ours, not unknown.
_FOREIGN_PARAMETERS = ('use_sim_time', 'start_type_description_service')
_SHUTDOWN_ANSWER_SECONDS = 0.2  # spinning after a stop request, for pending answers to go out


def _descriptor(spec: ParameterSpec) -> ParameterDescriptor:
    # Dynamic typing and no rclpy ranges: wrong types and values reach the one check the
    # node and replay share (one line, exit 2), not an rclpy traceback; the description
    # states the range.
    return ParameterDescriptor(description=spec.help, read_only=True, dynamic_typing=True)


def _ros_default(spec: ParameterSpec):
    return list(spec.default) if spec.kind is tuple else spec.default


class MapConsistencyNode(Node):
    """The `map_consistency` node (see docs/node.md for its contract).

    Parameters
    ----------
    kwargs: rclpy Node's keyword arguments (context, parameter_overrides, ...).
    """

    def __init__(self, **kwargs) -> None:
        super().__init__('map_consistency', **kwargs)
        values = self._declare_parameters()
        for warning in unknown_parameters(self._override_names()):
            self.get_logger().warning(warning)
        config = Configuration.from_values(values)
        self._settings: NodeSettings = config.node
        feed_settings = config.feed
        self.pipeline = LivePipeline(config.consistency, config.monitor, feed_settings,
                                     config.explanation)
        tuning = config.tuning
        wake = threading.Event()  # records queued, a job submitted, a stop
        self.engine = Engine(self.pipeline, self._settings, self.get_logger(), wake)
        self.intake = Intake(self, self._settings, feed_settings,
                             self.pipeline.feed.monitor_settings.max_buffered_scans, wake)
        self.outputs = Outputs(self, self._settings, self.engine, self.intake)
        self.intake.subscribe()
        self.node_services = Services(self, self.engine, self.outputs, tuning, self._settings)
        self.service_host = self.node_services.host
        # a steady timer: diagnostics go on (and turn STALE) when a simulated clock pauses
        self.create_timer(self._settings.diagnostics_period, self.outputs.publish_diagnostics,
                          callback_group=MutuallyExclusiveCallbackGroup(),
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.engine.start(self.intake, self.outputs)

    def _declare_parameters(self) -> dict:
        values = {}
        for spec in PARAMETERS:
            value = self.declare_parameter(spec.name, _ros_default(spec),
                                           _descriptor(spec)).value
            # arrays come back as array.array or list: our check takes lists
            sequence = not isinstance(value, (str, bool, int, float)) and value is not None
            values[spec.name] = list(value) if sequence else value
        return values

    def _override_names(self) -> list[str]:
        # rclpy keeps every --params-file / -p value for this node here, declared or not
        return [name for name in self._parameter_overrides
                if name not in _FOREIGN_PARAMETERS and not name.startswith('qos_overrides.')]

    def begin_shutdown(self) -> None:
        """Stop the worker; waiting services answer with a failure."""
        self.engine.begin_stop()

    @property
    def answering(self) -> bool:
        """Whether service calls are still being answered."""
        return self.node_services.answering

    @property
    def executor_kind(self) -> ExecutorKind:
        """The executor the node's messages need (NodeSettings.executor)."""
        return self._settings.executor

    @property
    def busy(self) -> bool:
        """Whether a retune or an update is still running (neither can be interrupted)."""
        return self.node_services.tuning or self.engine.alive

    def destroy_node(self) -> None:
        """Stop the engine (waiting briefly for its threads), then destroy the service host
        and the node."""
        self.engine.stop(timeout=_SHUTDOWN_ANSWER_SECONDS)
        self.service_host.destroy_node()
        super().destroy_node()


def _message_executor(node: MapConsistencyNode) -> Executor:
    """The executor that takes the node's messages (NodeSettings.executor)."""
    if node.executor_kind == ExecutorKind.EVENTS:
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError:  # an rclpy older than Jazzy's 7.1 releases that have it
            node.get_logger().warning('executor: events needs rclpy.experimental.'
                                      'EventsExecutor, which this rclpy lacks; using '
                                      'multi_threaded')
        else:
            return EventsExecutor()
    return MultiThreadedExecutor(num_threads=4)


def _spin_until(executor: Executor, stop: threading.Event) -> None:
    while not stop.is_set() and executor.context.ok():
        executor.spin_once(timeout_sec=0.05)


def main(args: list[str] | None = None) -> int:
    """Entry point of `map_consistency_node` and `python -m map_consistency_ros.ros.node`.

    SIGINT / SIGTERM stop the node within a second in every state: pending service calls are
    answered with a failure, a running retune is abandoned.

    Parameters
    ----------
    args: the command line rclpy reads (--ros-args ...); None: sys.argv.

    Returns
    -------
    The exit code: 0 after a stop; 2 for a bad parameter or slam_toolbox interfaces that
    cannot be imported (one line on stderr). With a retune or an update still running, the
    process ends at once with 0 (os._exit) instead of returning.
    """
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = threading.Event()
    for number in (signal.SIGINT, signal.SIGTERM):
        signal.signal(number, lambda *_: stop.set())
    node = None
    abandoned = False
    try:
        try:
            node = MapConsistencyNode()
        except (ParameterException, ValueError) as error:
            print(f'map_consistency: bad parameter: {error}', file=sys.stderr)
            return 2
        except slam_toolbox_graph.MissingInterfaces as error:
            print(f'map_consistency: {error}', file=sys.stderr)
            return 2
        executor = _message_executor(node)
        executor.add_node(node)
        service_executor = MultiThreadedExecutor(num_threads=4)
        service_executor.add_node(node.service_host)
        services_done = threading.Event()
        service_thread = threading.Thread(target=_spin_until, name='map_consistency_services',
                                          args=(service_executor, services_done), daemon=True)
        service_thread.start()
        _spin_until(executor, stop)
        node.begin_shutdown()
        # waiting calls fail at once; spin while their answers go out
        deadline = time.monotonic() + _SHUTDOWN_ANSWER_SECONDS
        answered = False
        while time.monotonic() < deadline and (node.answering or not answered):
            answered = not node.answering
            executor.spin_once(timeout_sec=0.02)
        services_done.set()
        service_thread.join(timeout=0.2)
        service_executor.shutdown(timeout_sec=0.1)
        executor.shutdown(timeout_sec=0.1)
    except ExternalShutdownException:
        pass
    finally:
        if node is not None:
            node.destroy_node()
            abandoned = node.busy
        rclpy.try_shutdown()
    if abandoned:
        # a retune's solver threads or a long update cannot be interrupted, and the
        # interpreter would wait for them
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)
    return 0


if __name__ == '__main__':
    sys.exit(main())
