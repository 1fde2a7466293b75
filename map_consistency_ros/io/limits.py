"""The plausible range of every number read from an input, each bound defined once.

A number outside its bounds is not a measurement but damage (a corrupted field, a unit mix-up,
an uninitialised value): the readers refuse it as bad input, naming the file and line
(io/carmen.py, io/g2o.py) or the topic and stamp (io/messages.py), instead of letting it reach
the geometry, where it would overflow or silently lose all precision.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from map_consistency_ros.core.geometry.se2 import MAX_EXTENT


class Limit(NamedTuple):
    """The plausible values of one kind of number: finite, |value| <= bound, and not negative
    unless `signed`."""

    bound: float
    unit: str
    signed: bool = True


# A coordinate or a laser reading beyond core's MAX_EXTENT (100 km) is no position on a 2D laser
# map (core/geometry/se2.py): the same bound as the pose graph's and the node's.
DISTANCE = Limit(MAX_EXTENT, 'm')

# Headings are wrapped to (-pi, pi]: beyond a thousand radians (160 turns) a float has lost
# the precision wrapping needs (1e200 rad wraps to an arbitrary angle).
HEADING = Limit(1e3, 'rad')

# A beam's bearing lies within a turn of the sensor axis either way, whatever the driver's
# convention (centred, from zero, either direction); twice that leaves room for rounding.
SCAN_ANGLE = Limit(4 * math.pi, 'rad')

# Stamps count seconds since an epoch (the Unix one, the start of a log): never negative, and
# below 2**31 s, the largest second a ROS Time (int32 sec) carries.
STAMP = Limit(2.0 ** 31 - 1, 's', signed=False)


def implausible(values, limit: Limit) -> tuple[int, str] | None:
    """The first value outside `limit`, and why.

    Parameters
    ----------
    values: a number or an array of numbers.
    limit: their plausible range (DISTANCE, HEADING, SCAN_ANGLE, STAMP).

    Returns
    -------
    (index in the flattened values, reason such as "1e+200 is beyond 1000 rad"); None when
    every value is plausible.
    """
    values = np.asarray(values, dtype=np.float64).reshape(-1)
    with np.errstate(invalid='ignore'):
        good = np.abs(values) <= limit.bound  # NaN compares False: refused too
        if not limit.signed:
            good &= values >= 0.0
    if good.all():
        return None
    index = int(np.flatnonzero(~good)[0])
    value = float(values[index])
    if not math.isfinite(value):
        reason = f'{value!r} is not finite'
    elif value < 0.0 and not limit.signed:
        reason = f'{value!r} is negative'
    else:
        reason = f'{value!r} is beyond {limit.bound:g} {limit.unit}'
    return index, reason
