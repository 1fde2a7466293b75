"""Growing arrays by rows; read-only views; runs of a mask."""
import numpy as np

import pytest

from map_consistency_ros.core.geometry import read_only, spans, true_runs, with_rows


def test_rows_are_kept_and_the_new_ones_filled():
    array = np.arange(6.0).reshape(3, 2)
    grown = with_rows(array, 5, fill=-1)
    np.testing.assert_array_equal(grown[:3], array)
    np.testing.assert_array_equal(grown[3:], -1)
    assert grown.dtype == array.dtype and grown is not array
    grown[0, 0] = 99.0
    assert array[0, 0] == 0.0  # a new array, the old one untouched (snapshots share it)
    np.testing.assert_array_equal(with_rows(array, 2), array[:2])
    flags = with_rows(np.ones(2, dtype=bool), 4)
    assert flags.tolist() == [True, True, False, False]


def test_a_read_only_view_follows_its_owner_who_may_still_write():
    owner = np.zeros(4)
    view = read_only(owner[:3])
    with pytest.raises(ValueError, match='read-only'):
        view[0] = 1.0
    owner[0] = 5.0  # the owner keeps writing (appends past a cached view, for example)
    assert owner.flags.writeable and view[0] == 5.0


def test_spans_lay_ranges_end_to_end_as_a_loop_would():
    low, high = np.array([3, 7, 7, 0]), np.array([5, 7, 10, 2])
    values, owners = spans(low, high)
    expected = [(value, k) for k, (a, b) in enumerate(zip(low, high)) for value in range(a, b)]
    assert values.tolist() == [value for value, _ in expected] == [3, 4, 7, 8, 9, 0, 1]
    assert owners.tolist() == [k for _, k in expected] == [0, 0, 2, 2, 2, 3, 3]
    empty_values, empty_owners = spans(np.zeros(0, np.int64), np.zeros(0, np.int64))
    assert empty_values.size == 0 and empty_owners.size == 0


@pytest.mark.parametrize('mask', [[], [False], [True], [True, True, False, True],
                                  [False, True, True, True, False, False, True, True]])
def test_true_runs_are_the_runs_a_loop_finds(mask):
    expected, start = [], None
    for index, value in enumerate(mask + [False]):
        if value and start is None:
            start = index
        elif not value and start is not None:
            expected.append([start, index])
            start = None
    runs = true_runs(np.array(mask, dtype=bool))
    assert runs.shape == (len(expected), 2) and runs.tolist() == expected
