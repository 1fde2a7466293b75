"""The second stage on degenerate maps: a robot standing still (identical scans), a corridor of
two parallel walls, a single scan, scans without a valid beam, no scans, and registrations whose
covariances are singular or not finite. Never an exception; an undetermined correction is never
a misalignment."""
import dataclasses
import math

import numpy as np
import pytest

from map_consistency_ros.core.consistency import check_consistency, statistics
from map_consistency_ros.core.geometry import ScanSet, SensorModel
from map_consistency_ros.core.verdict import (MISALIGNED, NOTHING_TO_JUDGE, ExplanationSettings,
                                              RegistrationCache, check_map, explain,
                                              register_submaps, surface_points)
from map_consistency_ros.evaluation.suite import displace
from map_consistency_ros.io import carmen

SCANS = 290  # the first 290 Intel scans: a loop through the building


@pytest.fixture(scope='module')
def intel(shared_data):
    log = carmen.read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    return log, carmen.sensor_model(log, max_range=8.0)


# ---------------------------------------------------------------- the numeric kernel

def test_mahalanobis_of_a_regular_covariance_is_the_quadratic_form():
    rng = np.random.default_rng(1)
    factors = rng.normal(size=(50, 3, 3))
    covariance = factors @ np.swapaxes(factors, 1, 2) + 0.01 * np.eye(3)
    delta = rng.normal(size=(50, 3))
    expected = np.einsum('ei,eij,ej->e', delta, np.linalg.inv(covariance), delta)
    assert np.allclose(statistics.mahalanobis_squared(delta, covariance), expected, rtol=1e-9)


@pytest.mark.parametrize('covariance', [
    np.zeros((3, 3)),  # a fit that left no residual
    np.diag([1e-4, 1e-4, 0.0]),  # rank 2
    np.diag([1e-4, 1e-4, 1e-20]),  # rank 2 to rounding
    np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),  # singular, off-diagonal
    np.full((3, 3), np.inf),  # an undetermined registration
    np.diag([np.nan, 1.0, 1.0]),
    -np.eye(3),  # not a covariance
], ids=['zero', 'rank2', 'rank2-rounding', 'singular', 'inf', 'nan', 'negative'])
def test_a_covariance_that_does_not_determine_the_correction_gives_nan(covariance):
    delta = np.array([[0.3, -0.1, 0.02]])
    with np.errstate(all='raise'):  # no warning either: the degenerate rows are set aside
        assert np.isnan(statistics.mahalanobis_squared(delta, covariance[None])).all()


def test_mahalanobis_of_no_rows_and_of_a_non_finite_delta():
    assert statistics.mahalanobis_squared(np.zeros((0, 3)), np.zeros((0, 3, 3))).shape == (0,)
    value = statistics.mahalanobis_squared(np.array([[np.nan, 0.0, 0.0], [1.0, 0.0, 0.0]]),
                                           np.stack([np.eye(3), np.eye(3)]))
    assert np.isnan(value[0]) and value[1] == 1.0


# ---------------------------------------------------------------- degenerate registrations

def _room(poses, noise):
    """Ranges of a 180-beam scanner in an empty 8 x 5 m room, and its model."""
    model = SensorModel(-math.pi / 2, math.pi / 180, 8.0)
    angles = model.bearings(180)
    ranges = np.empty((len(poses), 180))
    for row, (x, y, theta) in enumerate(poses):
        c, s = np.cos(theta + angles), np.sin(theta + angles)
        with np.errstate(divide='ignore'):
            tx = np.where(c > 0, (8.0 - x) / c, np.where(c < 0, -x / c, np.inf))
            ty = np.where(s > 0, (5.0 - y) / s, np.where(s < 0, -y / s, np.inf))
        ranges[row] = np.minimum(tx, ty)
    ranges += np.random.default_rng(0).normal(0.0, noise, ranges.shape)
    return ranges, model


def test_identical_scans_register_with_a_zero_covariance_that_determines_nothing():
    # A robot standing still, its laser reading the same ranges: every query point lies on a
    # reference point, the fit leaves no residual, and its covariance is the zero matrix that
    # a matrix inverse rejects (the crash of issue 29).
    ranges, model = _room(np.tile([3.0, 2.0, 0.3], (20, 1)), noise=0.0)
    scans = ScanSet.from_ranges(ranges, np.tile([3.0, 2.0, 0.3], (20, 1)), model)
    found = register_submaps(surface_points(scans.endpoints, scans.valid),
                             np.array([[0, 5, 10, 20]]))
    assert found.determined[0] and not found.covariances[0].any()
    assert np.isnan(statistics.mahalanobis_squared(found.corrections, found.covariances)).all()


class _DegenerateCache(RegistrationCache):
    """Registrations as computed, with every covariance replaced by `covariance`: what a
    standing-still, collinear or single-viewpoint submap gives."""

    def __init__(self, covariance):
        super().__init__()
        self.covariance = covariance

    def register(self, scans, tasks, settings):
        found = super().register(scans, tasks, settings)
        return dataclasses.replace(found, covariances=np.broadcast_to(
            self.covariance, found.covariances.shape).copy())


@pytest.mark.parametrize('covariance', [np.zeros((3, 3)), np.diag([1e-4, 0.0, 1e-6]),
                                        np.full((3, 3), np.nan), np.full((3, 3), np.inf)],
                         ids=['zero', 'corridor', 'nan', 'inf'])
def test_singular_covariances_leave_the_corrections_undetermined(intel, covariance):
    log, model = intel
    poses = displace(log.laser_poses[:SCANS], 150, SCANS, math.radians(1.0), np.zeros(2))
    scans = ScanSet.from_ranges(log.ranges[:SCANS], poses, model)
    result = check_consistency(scans)
    assessment = explain(scans, result, cache=_DegenerateCache(covariance))
    assert assessment.explained_pairs.size > 0
    assert assessment.class_counts()[MISALIGNED] == 0  # no correction is determined
    for region in assessment.misalignments:  # a gross error at most, no correction claimed
        assert not region.registered


# ---------------------------------------------------------------- degenerate maps

def test_a_map_standing_still_between_its_scans_gets_a_verdict(intel):
    # Every scan three times over (a full-density log of a robot that waits at each keyframe,
    # its laser reading the same ranges), the later half turned by a degree.
    log, model = intel
    repeated = np.repeat(np.arange(SCANS), 3)
    poses = displace(log.laser_poses[repeated], 450, 3 * SCANS, math.radians(1.0), np.zeros(2))
    assessment = check_map(ScanSet.from_ranges(log.ranges[repeated], poses, model))
    assert not assessment.consistent
    for region in assessment.misalignments:
        assert region.registered and np.isfinite(region.correction).all()
        assert np.isfinite(region.correction_std).all() and math.isfinite(region.displacement)


def _corridor(poses, half_width=1.0):
    """Ranges of a 361-beam scanner between two endless parallel walls y = +-half_width."""
    model = SensorModel(-math.pi / 2, math.pi / 360, 8.0)
    angles = model.bearings(361)
    ranges = np.empty((len(poses), angles.size))
    for row, (_, y, theta) in enumerate(poses):
        s = np.sin(theta + angles)
        with np.errstate(divide='ignore'):
            ranges[row] = np.where(s > 0, (half_width - y) / s,
                                   np.where(s < 0, (-half_width - y) / s, np.inf))
    return ranges + np.random.default_rng(0).normal(0.0, 0.01, ranges.shape), model


@pytest.mark.parametrize('shift, consistent', [((0.5, 0.0), True), ((0.0, 0.3), False)],
                         ids=['along', 'across'])
def test_a_corridor_of_two_parallel_walls(shift, consistent):
    # Down a 15 m corridor and back; the way back displaced. Along the axis the walls cannot
    # tell (nothing to see, nothing to correct); across it they disagree by 0.3 m.
    x = np.linspace(0.0, 15.0, 60)
    true = np.concatenate([np.stack([x, 0 * x, 0 * x], 1),
                           np.stack([x[::-1], 0 * x, np.full(60, math.pi)], 1)])
    ranges, model = _corridor(true)
    poses = true.copy()
    poses[60:, :2] += shift
    assessment = check_map(ScanSet.from_ranges(ranges, poses, model))
    assert assessment.consistent is consistent
    if not consistent:
        (region,) = assessment.misalignments
        assert (region.scans >= 60).mean() > 0.9  # the way back moved
        # caught; its correction is measured when the registrations confirm it, else the
        # region is judged as beyond registration (no size)
        assert not region.registered or abs(region.correction[1]) == pytest.approx(0.3, abs=0.05)


def test_a_single_scan_and_no_scan(intel):
    log, model = intel
    for count in (1, 0):
        assessment = check_map(ScanSet.from_ranges(log.ranges[:count], log.laser_poses[:count],
                                                   model))
        assert assessment.outcome == NOTHING_TO_JUDGE and not assessment.consistent
        assert assessment.explained_pairs.size == 0
        assert assessment.summary_line().startswith('NOTHING TO JUDGE')


def test_scans_without_a_valid_beam(intel):
    # No return at all (an open field, a blinded laser): empty point sets, in part or in whole.
    log, model = intel
    poses = displace(log.laser_poses[:SCANS], 150, SCANS, math.radians(1.0), np.zeros(2))
    ranges = log.ranges[:SCANS].copy()
    ranges[140:160] = np.inf
    assessment = check_map(ScanSet.from_ranges(ranges, poses, model))
    assert not assessment.consistent  # the turned stretch is still found around the gap
    ranges[:] = np.inf
    empty = check_map(ScanSet.from_ranges(ranges, poses, model))
    assert empty.outcome == NOTHING_TO_JUDGE
    assert empty.result.summary()['overlapping_pairs'] == 0


def test_one_wall_seen_from_one_place_determines_no_slide_along_it():
    # Collinear points (a robot facing a single long wall): the wall fixes the distance to it
    # and the heading, never the slide along it; registration says so or its covariance does.
    model = SensorModel(-math.pi / 4, math.pi / 360, 8.0)
    angles = model.bearings(181)
    poses = np.tile([0.0, 0.0, math.pi / 2], (10, 1))
    poses[5:, 0] += 0.2  # the second visit displaced along the wall
    ranges = np.tile(3.0 / np.cos(angles), (10, 1))
    ranges += np.random.default_rng(0).normal(0.0, 0.005, ranges.shape)
    scans = ScanSet.from_ranges(ranges, poses, model)
    found = register_submaps(surface_points(scans.endpoints, scans.valid),
                             np.array([[0, 5, 5, 10]]))
    value = statistics.mahalanobis_squared(found.corrections, found.covariances)[0]
    along = np.array([1.0, 0.0, 0.0])
    assert (not found.determined[0] or np.isnan(value)
            or along @ found.covariances[0] @ along > 50 * found.covariances[0, 1, 1])
    # nothing on the wall shows the slide: no scan sees another's free space occupied
    assert check_map(scans).consistent


def test_submaps_of_single_scans(intel):
    # block 1 and no margin: every registration sees one viewpoint on each side
    log, model = intel
    poses = displace(log.laser_poses[:SCANS], 150, SCANS, math.radians(1.0), np.zeros(2))
    scans = ScanSet.from_ranges(log.ranges[:SCANS], poses, model)
    settings = ExplanationSettings(block=1, margin=0)
    assessment = explain(scans, check_consistency(scans), settings)
    assert assessment.explained_pairs.size > 0
    for region in assessment.misalignments:
        assert region.registered is bool(np.isfinite(region.correction).all())
