"""The engine's UpdateFirst: the second stage yields the interpreter to first-stage updates.

Event-driven: every wait below is bounded by a generous timeout and asserts an order of events,
not a duration, so a loaded machine cannot fail them.
"""
import sys
import threading

from map_consistency_ros.ros.engine import UpdateFirst

LONG = 30.0  # s: a wait that only an event ends


def _calls(done: threading.Event, count: list) -> None:
    """Python calls until `done`: each one is a profile event."""
    while not done.is_set():
        count[0] += 1
        len(count)


def test_the_yielding_thread_waits_for_an_update_to_end():
    gate = UpdateFirst(wait=LONG, run=0.0)
    done, count, pause = threading.Event(), [0], threading.Event()

    def explainer():
        with gate.yielding():
            _calls(done, count)

    def advances(beyond: int) -> bool:
        """Whether `count` passes `beyond` within LONG seconds."""
        for _ in range(int(LONG / 0.01)):
            if count[0] > beyond:
                return True
            pause.wait(0.01)
        return False

    thread = threading.Thread(target=explainer)
    thread.start()
    try:
        assert advances(0)  # no update: it runs
        with gate.updating():
            pause.wait(0.05)  # it reaches its next profile event and waits there
            before = count[0]
            pause.wait(0.2)  # the worker's update runs; the explainer must not
            # at most the loop step it was in when the update began
            assert count[0] <= before + 1
        assert advances(before + 1)  # the update is over: it runs again
    finally:
        done.set()
        thread.join(LONG)
    assert not thread.is_alive()


def test_an_idle_worker_never_blocks_the_yielding_thread():
    gate = UpdateFirst(wait=LONG, run=0.0)
    with gate.yielding():
        for _ in range(1000):
            len('calls')  # each a profile event; a wait here would take LONG seconds
    assert not gate.updating_now


def test_after_a_bounded_wait_the_yielding_thread_runs_on():
    gate = UpdateFirst(wait=0.0, run=LONG)  # waits nothing, then runs LONG seconds unhindered
    finished = threading.Event()

    def explainer():
        with gate.yielding():
            for _ in range(1000):
                len('calls')
        finished.set()

    with gate.updating():  # an update that never ends while the explainer runs
        thread = threading.Thread(target=explainer)
        thread.start()
        assert finished.wait(LONG)
    thread.join(LONG)


def test_paused_opens_the_gate_and_restores_it():
    gate = UpdateFirst()
    with gate.updating():
        assert gate.updating_now
        with gate.paused():  # the worker waits for the second stage or runs it itself
            assert not gate.updating_now
        assert gate.updating_now
    assert not gate.updating_now
    with gate.paused():  # a service job outside an update: stays open
        assert not gate.updating_now
    assert not gate.updating_now


def test_the_hook_is_the_calling_threads_only_and_removed_after():
    gate = UpdateFirst()
    seen = {}

    def other():
        seen['other'] = sys.getprofile()

    with gate.yielding():
        inside = sys.getprofile()
        thread = threading.Thread(target=other)
        thread.start()
        thread.join(LONG)
    assert inside is not None
    assert seen['other'] is None
    assert sys.getprofile() is None
