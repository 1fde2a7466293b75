"""Which pairs the monitor measures: the partner budget and the local window."""
import numpy as np

from map_consistency_ros.core.live._pair_cache import key_slots
from map_consistency_ros.core.live._pair_selection import PartnerBudget, local_pair_keys


def _line():
    """Laser poses of slots on a line, slot s at x = s."""
    return lambda slots: np.column_stack([np.asarray(slots, float), np.zeros((len(slots), 2))])


def test_a_crowded_keyframe_keeps_the_nearest_of_each_visit_stably():
    # slot 30 arrives overlapping slots 0..5 (a first visit) and 20..27 (a second)
    partners = np.r_[0:6, 20:28]
    pairs = np.column_stack([partners, np.full(partners.size, 30)])
    budget = PartnerBudget(max_partners=4)
    kept = budget.select(pairs, np.array([30]), 31, _line())
    assert kept.tolist() == [[4, 30], [5, 30], [26, 30], [27, 30]]  # two nearest of each visit
    # moved later, the same pairs come back (chosen once, on arrival), whatever the poses now
    again = budget.select(pairs[::-1], np.zeros(0, dtype=np.int64), 31, lambda slots: None)
    assert sorted(again.tolist()) == kept.tolist()


def test_keyframes_crowded_in_one_update_keep_what_each_would_alone():
    rng = np.random.default_rng(4)
    poses = rng.uniform(-5, 5, (60, 3))
    laser = lambda slots: poses[np.asarray(slots)]  # noqa: E731
    # slots 50..59 arrive at once, each overlapping a random two or three runs of earlier ones
    pairs = np.array(sorted({(partner, slot) for slot in range(50, 60)
                             for start in rng.choice(45, 3, replace=False)
                             for partner in range(start, start + int(rng.integers(2, 9)))}))
    together = PartnerBudget(max_partners=6).select(pairs, np.arange(50, 60), 60, laser)
    alone = PartnerBudget(max_partners=6)
    one_by_one = np.concatenate([alone.select(pairs[pairs[:, 1] == slot], np.array([slot]), 60,
                                              laser) for slot in range(50, 60)])
    np.testing.assert_array_equal(together, one_by_one[np.lexsort(one_by_one.T[::-1])])
    assert len(together) < len(pairs)  # the budget bit


def _nearest_of_each_visit_oracle(partners, slot, budget, poses, gap=5):
    """The partners `slot` keeps, one by one: runs at most `gap` apart share the budget."""
    partners = sorted(partners)
    visits, run = [], [partners[0]]
    for partner in partners[1:]:
        if partner - run[-1] > gap:
            visits.append(run)
            run = []
        run.append(partner)
    visits.append(run)
    quota = max(budget // len(visits), 1)
    kept = set()
    for run in visits:
        distance = [float(np.hypot(*(poses[p, :2] - poses[slot, :2]))) for p in run]
        kept |= {run[i] for i in sorted(range(len(run)), key=lambda i: distance[i])[:quota]}
    return kept


def test_a_long_stream_keeps_what_each_keyframe_chose_on_arrival():
    rng = np.random.default_rng(11)
    poses = rng.uniform(-20, 20, (400, 3))
    laser = lambda slots: poses[np.asarray(slots)]  # noqa: E731
    budget, expected, every_pair = PartnerBudget(max_partners=5), set(), set()
    slot = 10
    while slot < 400:  # one to three keyframes per update, each revisiting random places
        new = np.arange(slot, min(slot + int(rng.integers(1, 4)), 400))
        pairs = {(partner, int(j)) for j in new for start in rng.choice(int(j) - 8, 2)
                 for partner in range(start, min(start + int(rng.integers(1, 12)), int(j)))}
        pairs = np.array(sorted(pairs))
        kept = budget.select(pairs, new, int(new[-1]) + 1, laser)
        for j in new.tolist():
            partners = pairs[pairs[:, 1] == j, 0].tolist()
            chosen = (set(partners) if len(partners) <= 5
                      else _nearest_of_each_visit_oracle(partners, j, 5, poses))
            expected |= {(partner, j) for partner in chosen}
        assert set(map(tuple, kept.tolist())) == expected & set(map(tuple, pairs.tolist()))
        every_pair |= set(map(tuple, pairs.tolist()))
        slot = int(new[-1]) + 1
    # every keyframe moved: the pairs each chose on arrival, nothing else, in their order
    pairs = np.array(sorted(every_pair))
    kept = budget.select(pairs, np.zeros(0, dtype=np.int64), 400, lambda slots: None)
    assert list(map(tuple, kept.tolist())) == sorted(expected)
    assert len(expected) < len(every_pair)  # the budget bit
    # once and for all: a budgeted slot named new again keeps its first choice
    crowded = int(pairs[-1, 1])
    again = np.array([[partner, crowded] for partner in range(crowded)])
    assert set(map(tuple, budget.select(again, np.array([crowded]), 400, laser).tolist())) == {
        pair for pair in expected if pair[1] == crowded}


def test_keyframes_within_the_budget_and_no_budget_keep_every_pair():
    pairs = np.array([[0, 3], [1, 3], [2, 3]])
    np.testing.assert_array_equal(
        PartnerBudget(3).select(pairs, np.array([3]), 4, _line()), pairs)
    np.testing.assert_array_equal(
        PartnerBudget(0).select(pairs, np.array([3]), 4, _line()), pairs)
    assert PartnerBudget(2).select(pairs, np.array([3]), 4, _line()).tolist() == [[1, 3],
                                                                                 [2, 3]]


def test_the_local_window_pairs_each_keyframe_with_its_predecessors_in_stamp_order():
    order = np.array([0, 1, 3, 2])  # slot 3 stamped before slot 2
    keys, appended = local_pair_keys(order, np.array([3]), reach=2)
    assert appended and key_slots(keys).tolist() == [[1, 2], [2, 3]]  # the new rank 3: slot 2
    keys, appended = local_pair_keys(order, np.array([2]), reach=2)
    assert not appended  # an insertion: every window pair
    assert key_slots(keys).tolist() == [[0, 1], [0, 3], [1, 2], [1, 3], [2, 3]]
