"""The node's intake without a middleware: when an input counts as arrived."""
from __future__ import annotations

import threading
from types import SimpleNamespace

import numpy as np

from map_consistency_ros.core.configuration import NodeSettings
from map_consistency_ros.core.live import (Constraints, DroppedScans, FeedSettings,
                                           KeyframeEstimate, Scan)
from map_consistency_ros.core.geometry import SensorModel
from map_consistency_ros.ros import intake as intake_module
from map_consistency_ros.ros.intake import Intake


class _Clock:
    """time.monotonic for the intake, which decoding advances."""

    def __init__(self) -> None:
        self.seconds = 100.0

    def monotonic(self) -> float:
        return self.seconds


def _node() -> SimpleNamespace:
    clock = SimpleNamespace(now=lambda: SimpleNamespace(nanoseconds=0))
    return SimpleNamespace(get_clock=lambda: clock)


def test_an_input_arrives_when_its_callback_begins_so_decoding_counts_in_the_latency(
        monkeypatch):
    clock = _Clock()
    monkeypatch.setattr(intake_module, 'time', SimpleNamespace(monotonic=clock.monotonic))
    model = SensorModel(angle_min=-1.0, angle_increment=0.5, max_range=10.0)
    records = {'scan': Scan(stamp=1.0, ranges=np.ones(5), model=model),
               'constraints': Constraints(rows=np.zeros((0, 11))),
               'trajectory': KeyframeEstimate(stamps=np.zeros(1), poses=np.zeros((1, 3)))}

    def decoding(record):
        def decode(*_, **__):
            clock.seconds += 2.0  # a long Path takes its time to decode
            return record
        return decode

    monkeypatch.setattr(intake_module.messages, 'record_from_cdr',
                        decoding(records['trajectory']))
    intake = Intake(_node(), NodeSettings(), FeedSettings(), 10, threading.Event())
    for topic in ('scan', 'constraints'):
        monkeypatch.setattr(intake_module.messages, 'to_record', decoding(records[topic]))
        getattr(intake, f'_on_{topic}')(object())
    intake._on_trajectory(b'')
    taken = intake.take()
    # each arrived before its own decoding: 100, 102 and 104, not 102, 104 and 106
    assert [arrival for arrival, _ in taken] == [100.0, 102.0, 104.0]
    assert all(record is records[topic] for (_, record), topic in
               zip(taken, ('scan', 'constraints', 'trajectory')))
    assert clock.seconds == 106.0


def test_every_scan_received_is_queued_handed_or_handed_on_as_dropped(monkeypatch):
    """A full queue drops its oldest scans and unreadable scans are refused; both reach the
    pipeline's account as one DroppedScans record, and the figures add up at every step."""
    model = SensorModel(angle_min=-1.0, angle_increment=0.5, max_range=10.0)

    def convert(msgtype, msg, max_range):
        if msg.ranges == 1:
            raise ValueError('scan has 1 ranges; at least 2 are needed')
        return Scan(stamp=msg.header.stamp.sec, ranges=np.ones(5), model=model)

    def message(stamp: int, ranges: int = 5) -> SimpleNamespace:
        return SimpleNamespace(header=SimpleNamespace(stamp=SimpleNamespace(sec=stamp,
                                                                            nanosec=0)),
                               ranges=ranges)

    monkeypatch.setattr(intake_module.messages, 'to_record', convert)
    node = _node()
    node.get_logger = lambda: SimpleNamespace(warning=lambda text: None)
    intake = Intake(node, NodeSettings(), FeedSettings(), 3, threading.Event())

    def balanced() -> None:
        figures = intake.figures()
        assert figures.received_scans == (figures.queued_scans + figures.handed_scans
                                          + figures.lost_scans + figures.unreadable_scans)

    for scan in (message(1), message(2), message(9, ranges=1), message(3), message(4),
                 message(5)):
        intake._on_scan(scan)
        balanced()
    figures = intake.figures()
    assert (figures.received_scans, figures.queued_scans, figures.lost_scans,
            figures.unreadable_scans) == (6, 3, 2, 1)
    taken = [record for _, record in intake.take()]
    balanced()
    assert isinstance(taken[0], DroppedScans) and taken[0].unreadable.tolist() == [9.0]
    assert taken[0].lost.tolist() == [1.0, 2.0]
    assert [record.stamp for record in taken[1:]] == [3.0, 4.0, 5.0]
    assert intake.figures().handed_scans == 6
    assert len(intake.take()) == 0  # nothing dropped since: no record
