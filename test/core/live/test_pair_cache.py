"""The monitor's pair cache: keys, insert / retain / drop, views that outlive drops."""
import numpy as np

from map_consistency_ros.core.geometry import PairMeasures
from map_consistency_ros.core.live._pair_cache import PairCache, key_slots, pair_keys


def _measures(keys: np.ndarray, sums) -> PairMeasures:
    sums = np.asarray(sums, dtype=np.float64)
    largest = np.stack([sums / 2, sums / 4], axis=1)
    return PairMeasures(pairs=key_slots(keys), distance_sum=sums,
                        point_count=np.full(sums.size, 3, dtype=np.int64), largest=largest)


def test_keys_name_a_pair_in_either_order():
    keys = pair_keys(np.array([5, 0, 2**30]), np.array([2, 7, 1]))
    assert key_slots(keys).tolist() == [[2, 5], [0, 7], [1, 2**30]]
    assert pair_keys(np.array([2]), np.array([5]))[0] == keys[0]


def test_inserted_pairs_are_kept_in_order_and_trimmed_once():
    cache = PairCache(keep_largest=2, trim=1)
    keys = pair_keys(np.array([0, 0, 1]), np.array([1, 2, 2]))
    cache.insert(keys, _measures(keys, [4.0, 8.0, 2.0]))
    measures = cache.measures(None)
    assert measures.pairs.tolist() == [[0, 1], [0, 2], [1, 2]]
    trimmed_sum, trimmed_count = cache.robust()
    np.testing.assert_array_equal(trimmed_sum, [2.0, 4.0, 1.0])  # minus the largest (sum / 2)
    np.testing.assert_array_equal(trimmed_count, [2, 2, 2])
    # over stamp-order ranks (slot 2 first): rows stay (i, j) with i < j
    assert cache.measures(np.array([1, 2, 0])).pairs.tolist() == [[1, 2], [0, 1], [0, 2]]


def test_dropping_pairs_leaves_views_handed_out_before_untouched():
    cache = PairCache(keep_largest=2, trim=0)
    cache.mark_new(np.array([0, 1, 2]))
    keys = pair_keys(np.array([0, 0, 1]), np.array([1, 2, 2]))
    cache.insert(keys, _measures(keys, [1.0, 2.0, 3.0]))
    before, generation = cache.measures(None), cache.generation
    cache.retain(keys[[0, 2]])
    assert cache.generation == generation + 1
    assert cache.pairs.tolist() == [[0, 1], [1, 2]]
    cache.drop_slots(np.array([0]), slot_count=3)
    assert cache.pairs.tolist() == [[1, 2]] and cache.generation == generation + 2
    cache.insert(pair_keys(np.array([0]), np.array([1])), _measures(keys[:1], [9.0]))
    np.testing.assert_array_equal(before.distance_sum, [1.0, 2.0, 3.0])
    assert not before.distance_sum.flags.writeable


def test_first_rows_bound_where_a_new_slot_s_pairs_start():
    cache = PairCache(keep_largest=2, trim=0)
    cache.mark_new(np.array([0, 1]))
    first = pair_keys(np.array([0]), np.array([1]))
    cache.insert(first, _measures(first, [1.0]))
    cache.mark_new(np.array([2]))
    later = pair_keys(np.array([0, 1]), np.array([2, 2]))
    cache.insert(later, _measures(later, [1.0, 1.0]))
    assert cache.first_rows(4).tolist() == [0, 0, 1, 0]  # slot 3 unknown: from the start
    cache.retain(later)  # entries move down: no bound is kept
    assert cache.first_rows(3).tolist() == [0, 0, 0]
