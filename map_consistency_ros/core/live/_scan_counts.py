"""What became of every scan received: the one account the node's /diagnostics and ~/report
and replay's report give (core/live/_feed.py keeps it, MonitorSnapshot.scan_counts carries it).

Invariant (`ScanCounts.balanced`): every scan received is counted in exactly one category,

    received == keyframes + folded + waiting + passed_over
                + lost_in_queue + pushed_out + unplaced + rejected + earlier_sessions,

in every ScanCounts the live pipeline gives and in the node's (`with_intake`), whatever the
timing: each count is read from one state at one instant, and a scan leaves one category in
the same step that puts it into another. The categories of the current session (all but
`earlier_sessions`) start from zero at a reset; the scans that confirmed an automatic reset
belong to the new session.
"""
from __future__ import annotations

from dataclasses import dataclass, fields, replace


@dataclass(frozen=True)
class ScanCounts:
    """Scans received since the start, by what became of them (see the module docstring)."""

    received: int = 0  # scan messages received since the start
    keyframes: int = 0  # keyframes of the current map: each a viewpoint of the test
    folded: int = 0  # folded into a viewpoint of the current map (not tested on their own)
    # not decided yet: queued in the node, held until a jump back in stamps is confirmed or
    # skipped, waiting for a pose (single poses) or buffered until a pose names them
    waiting: int = 0
    # the pose source made no keyframe of them: the estimate went past their stamps without
    # naming them, or (single poses) the robot had not moved keyframe_distance / keyframe_angle
    passed_over: int = 0
    lost_in_queue: int = 0  # lost: the node's queue was full (max_buffered_scans)
    pushed_out: int = 0  # lost: the buffer was full before any pose reached their stamps
    unplaced: int = 0  # lost: single poses: no pose before or around their stamps
    # bad input: unreadable, another beam geometry, a keyframe's or a buffered scan's stamp, a
    # stray old stamp
    rejected: int = 0
    earlier_sessions: int = 0  # received before the last reset, whatever became of them

    @property
    def lost(self) -> int:
        """Scans the node lost: its queue or buffer was full, or no pose placed them."""
        return self.lost_in_queue + self.pushed_out + self.unplaced

    def balanced(self) -> bool:
        """Whether every scan received is in exactly one category.

        Returns
        -------
        True when `received` equals the sum of the other fields and none is negative.
        """
        values = [getattr(self, field.name) for field in fields(self)]
        return min(values) >= 0 and self.received == sum(values[1:])

    def with_intake(self, received: int, queued: int, handed: int, lost_in_queue: int = 0,
                    unreadable: int = 0) -> ScanCounts:
        """These counts (a pipeline's) with the scans of a queue in front of the pipeline.

        Parameters
        ----------
        received: scans the queue received since the start.
        queued: scans in the queue now.
        handed: scans the queue handed to the pipeline since the start (scan records and the
            counts of DroppedScans records): these counts must have been read before, so
            that every scan they hold was handed (handed >= self.received); those handed
            and not in them yet are on their way and count as waiting.
        lost_in_queue: scans dropped from the full queue and not handed over yet.
        unreadable: unreadable scans not handed over yet.

        Returns
        -------
        The counts of every scan the queue received; balanced when these are and
        received == queued + handed + lost_in_queue + unreadable.
        """
        on_the_way = handed - self.received
        return replace(self, received=received, waiting=self.waiting + queued + on_the_way,
                       lost_in_queue=self.lost_in_queue + lost_in_queue,
                       rejected=self.rejected + unreadable)
