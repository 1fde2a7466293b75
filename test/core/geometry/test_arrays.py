"""Growing arrays by rows; read-only views."""
import numpy as np

import pytest

from map_consistency_ros.core.geometry import read_only, with_rows


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
