"""The second stage on real Intel scans: people and moved doors are changes, a rotated stretch
is a misalignment, a gross error is never a change."""
import numpy as np
import pytest

from map_consistency_ros.core.consistency import check_consistency
from map_consistency_ros.core.geometry import ScanSet, se2, viewpoint_rows
from map_consistency_ros.core.verdict import (CHANGE, MISALIGNED, PAIR_CLASSES, UNREGISTERED,
                                              ExplanationSettings, PointMoments, RegistrationCache,
                                              agreeing_registrations, check_map,
                                              corrections_confirmed, explain, longest_run,
                                              longest_travel)
from map_consistency_ros.evaluation.suite import displace
from map_consistency_ros.io import carmen

# The first 290 scans of the Intel lab (the bundled demo map): a loop through the building.
SCANS = 290


@pytest.fixture(scope='module')
def intel(shared_data):
    log = carmen.read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    return log, carmen.sensor_model(log, max_range=8.0)


def _map(intel, poses=None, ranges=None):
    log, model = intel
    return ScanSet.from_ranges(log.ranges[:SCANS] if ranges is None else ranges,
                               log.laser_poses[:SCANS] if poses is None else poses, model)


@pytest.fixture(scope='module')
def corrected(intel):
    return check_map(_map(intel))


def _obstacle(intel, scan, first_beam, beams, distance):
    """Ranges with an object `distance` m in front of `scan` across `beams` beams: what the
    scan would see had a person (or a door) stood there on that visit only."""
    log, _ = intel
    ranges = log.ranges[:SCANS].copy()
    ranges[scan, first_beam:first_beam + beams] = distance
    return ranges


def _pairs_of(assessment, scan):
    pairs = assessment.result.pairs[assessment.explained_pairs]
    return (pairs[:, 0] == scan) | (pairs[:, 1] == scan)


def test_the_corrected_map_passes_with_its_changes_reported(corrected):
    assert not corrected.result.consistent  # the paper's test flags it
    assert corrected.consistent
    counts = corrected.class_counts()
    assert counts['change'] > counts['misaligned']
    assert corrected.changes and all(place.points > 0 for place in corrected.changes)
    assert corrected.summary_line().startswith('CONSISTENT: no misalignment above 0.10 m; ')


@pytest.mark.parametrize('name,first_beam,beams,distance', [
    ('person', 0, 20, 1.1),  # a body 1.1 m to the right: about 0.4 m wide
    ('door', 40, 45, 1.6),  # a panel 1.6 m ahead across 45 degrees: about 1.2 m wide
])
def test_an_object_on_one_visit_is_a_change(intel, corrected, name, first_beam, beams, distance):
    scan = 250  # the robot comes back to where scans 0-40 saw open space
    ranges = _obstacle(intel, scan, first_beam, beams, distance)
    assessment = check_map(_map(intel, ranges=ranges))
    involved = _pairs_of(assessment, scan)
    assert involved.any(), f'the {name} makes pairs of scan {scan} fail'
    classes = [PAIR_CLASSES[code] for code in assessment.pair_classes[involved]]
    assert MISALIGNED not in classes and UNREGISTERED not in classes, classes
    assert classes.count(CHANGE) >= 0.5 * len(classes), classes
    assert assessment.consistent
    # The object is a changed place where it stood.
    scans = _map(intel, ranges=ranges)
    outline = scans.endpoints[scan, first_beam:first_beam + beams]
    nearest = min(np.hypot(*(outline - (place.x, place.y)).T).min()
                  for place in assessment.changes if scan in place.scans)
    assert nearest < 0.3


def test_a_one_degree_rotation_is_a_misalignment(intel):
    log, _ = intel
    poses = displace(log.laser_poses[:SCANS], 150, SCANS, np.radians(1.0), np.zeros(2))
    assessment = check_map(_map(intel, poses=poses))
    assert not assessment.consistent
    assert assessment.summary_line().startswith('INCONSISTENT: 1 misaligned region')
    (region,) = assessment.misalignments
    assert region.registered
    # The later side moved, against the scans before the seam it revisits.
    assert region.scans.min() >= 150 and (region.reference_scans < 150).mean() > 0.95
    # The correction turns the displaced stretch back by the degree it was turned.
    assert np.degrees(region.correction[2]) == pytest.approx(-1.0, abs=0.25)
    assert region.displacement > assessment.settings.misalignment_tolerance
    assert np.isfinite(region.correction_std).all() and (region.correction_std < 0.05).all()
    counts = assessment.class_counts()
    assert counts[MISALIGNED] > counts[CHANGE]


@pytest.mark.parametrize('shift', [1.5, 3.0])
def test_a_gross_error_is_never_a_change(intel, shift):
    log, _ = intel
    poses = displace(log.laser_poses[:SCANS], 150, SCANS, 0.0, np.array([shift, 0.0]))
    assessment = check_map(_map(intel, poses=poses))
    assert not assessment.consistent
    moved = np.concatenate([region.scans for region in assessment.misalignments])
    assert (moved >= 150).mean() > 0.9


def test_a_small_error_within_the_tolerance_passes(intel):
    log, _ = intel
    poses = displace(log.laser_poses[:SCANS], 150, SCANS, 0.0, np.array([0.03, 0.0]))
    assert check_map(_map(intel, poses=poses)).consistent


def test_a_map_that_passes_the_paper_test_is_not_explained(room_log):
    path, _, _ = room_log()
    log = carmen.read_carmen_log(path)
    scans = ScanSet.from_ranges(log.ranges, log.laser_poses, carmen.sensor_model(log))
    result = check_consistency(scans)
    assert result.consistent
    assessment = explain(scans, result)
    assert assessment.consistent and assessment.explained_pairs.size == 0
    assert assessment.summary_line() == ('CONSISTENT: no misalignment above 0.10 m; '
                                         '0 changed places (people, moved objects)')


def test_strict_keeps_the_paper_verdict(intel, corrected):
    strict = explain(_map(intel), corrected.result, ExplanationSettings(strict=True))
    assert not strict.consistent
    assert np.array_equal(strict.flagged, corrected.result.inconsistent)
    assert 'scans fail the paper\'s test (strict verdict)' in strict.summary_line()


def test_settings_are_checked():
    with pytest.raises(ValueError, match='misalignment_tolerance'):
        ExplanationSettings(misalignment_tolerance=-1.0)
    with pytest.raises(ValueError, match='gross_fraction'):
        ExplanationSettings(gross_fraction=1.0)
    for name, value in (('min_region_scans', 0), ('min_resolved_fraction', 1.5),
                        ('max_change_extent', 0.0), ('min_region_support', -1.0)):
        with pytest.raises(ValueError, match=name):
            ExplanationSettings(**{name: value})
    with pytest.raises(ValueError, match='scans for a result'):
        explain(ScanSet.from_ranges(np.ones((2, 4)), np.zeros((2, 3)),
                                    carmen.SensorModel(-1.0, 0.5, 8.0)),
                check_consistency(ScanSet.from_ranges(np.ones((3, 4)), np.zeros((3, 3)),
                                                      carmen.SensorModel(-1.0, 0.5, 8.0))))


def test_a_cache_gives_the_same_assessment_and_registers_only_what_changed(intel, corrected):
    log, _ = intel
    cache = RegistrationCache()
    first = explain(_map(intel), corrected.result, cache=cache)
    registered = len(cache)
    assert registered > 0
    assert first.summary_line() == corrected.summary_line()
    assert np.array_equal(first.pair_classes, corrected.pair_classes)
    # The same map again: nothing new to register.
    explain(_map(intel), corrected.result, cache=cache)
    assert len(cache) == registered
    # A loop closure moves the last scans: only the submaps holding them are registered again.
    poses = displace(log.laser_poses[:SCANS], 280, SCANS, 0.0, np.array([0.2, 0.0]))
    moved = _map(intel, poses=poses)
    again = explain(moved, check_consistency(moved), cache=cache)
    assert registered < len(cache) < 2 * registered
    fresh = explain(moved, again.result)
    assert again.summary_line() == fresh.summary_line()


def test_rms_displacement_in_closed_form_equals_moving_the_points(shared_data):
    log = carmen.read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    scans = ScanSet.from_ranges(log.ranges[:40], log.laser_poses[:40], carmen.sensor_model(log))
    rng = np.random.default_rng(4)
    transforms = np.column_stack([rng.normal(0.0, 0.3, 40), rng.normal(0.0, 0.3, 40),
                                  rng.normal(0.0, 0.05, 40)])
    transforms[0] = (0.0, 0.0, 1e-9)  # a turn too small for 1 - cos

    def direct(transform, rows):
        points = scans.endpoints[rows][scans.valid[rows]]
        moved = se2.compose(np.broadcast_to(transform, (len(points), 3)),
                            np.column_stack([points, np.zeros(len(points))]))[:, :2]
        return np.sqrt(np.mean(np.sum((moved - points) ** 2, axis=1)))

    moments = PointMoments.of(scans)
    rows = np.arange(40)
    expected = [direct(transforms[k], [k]) for k in rows]
    np.testing.assert_allclose(moments.displacement(transforms, rows), expected, rtol=1e-9,
                               atol=1e-15)
    together = np.array([3, 17, 29])
    assert moments.pooled(together).displacement(transforms[1:2])[0] == pytest.approx(
        direct(transforms[1], together), rel=1e-12)


@pytest.mark.parametrize('dataset,every', [('intel', 1), ('belgioioso', 1), ('fr079', 5)])
def test_whole_corrected_logs_pass(shared_data, dataset, every):
    """The corrected logs whole, as a user checks them: the paper's test flags each (people,
    furniture, doors), the verdict does not. Intel's end revisits a room whose furniture moved
    (registrations snap onto it); Belgioioso has a door seen from both sides of a wall (too
    little overlap to register); Freiburg 079 has single scans out of place."""
    from map_consistency_ros.evaluation.suite import CORRECTED_LOGS
    log = carmen.read_carmen_log(shared_data / CORRECTED_LOGS[dataset])
    scans = ScanSet.from_ranges(log.ranges[::every], log.laser_poses[::every],
                                carmen.sensor_model(log))
    assessment = check_map(scans)
    assert not assessment.result.consistent
    assert assessment.consistent, assessment.summary_line()
    assert not assessment.distorted


def _task_of_worst_pair(assessment, where):
    pairs = assessment.result.pairs[assessment.explained_pairs]
    i, j = pairs[where(pairs)][np.argmax(assessment.pair_displacements[where(pairs)])]
    return np.array([[max(i - 5, 0), i + 6, j - 5, min(j + 6, SCANS)]])


def test_a_correction_must_mend_more_than_it_breaks(intel):
    """Registrations are confirmed on every overlap between their two submaps: the correction
    that undoes a one-degree turn mends them; none, or one that turns the wrong way, does not."""
    log, _ = intel
    settings = ExplanationSettings()
    poses = displace(log.laser_poses[:SCANS], 150, SCANS, np.radians(1.0), np.zeros(2))
    turned = _map(intel, poses=poses)
    result = check_consistency(turned)
    tasks = _task_of_worst_pair(explain(turned, result),
                                lambda pairs: (pairs[:, 0] < 140) & (pairs[:, 1] >= 160))
    pivot = log.laser_poses[150, :2]

    def turn_about_the_seam(degrees):
        turn = np.radians(degrees)
        rotation = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
        return np.array([[*(pivot - rotation @ pivot), turn]])

    def confirmed(correction):
        return corrections_confirmed(turned, result, tasks, correction, settings)

    assert confirmed(turn_about_the_seam(-1.0)).all()
    assert not confirmed(np.zeros((1, 3))).any()
    assert not confirmed(turn_about_the_seam(1.0)).any()


def test_a_region_is_a_stretch_of_consecutive_scans():
    assert longest_run(np.array([562, 563, 622, 623, 624, 934, 938, 942, 943]), 5) == 4
    assert longest_run(np.array([3, 8, 13, 19]), 5) == 3
    assert longest_run(np.array([7]), 5) == 1 and longest_run(np.zeros(0, np.int64), 5) == 0


def test_a_gross_error_is_a_stretch_of_travel_not_a_robot_turning():
    # scans 0.4 m apart along x; 3..5 turn on the spot at x = 1.2
    positions = np.array([[0.0, 0], [0.4, 0], [0.8, 0], [1.2, 0], [1.2, 0], [1.2, 0],
                          [1.6, 0], [2.0, 0], [2.4, 0], [2.8, 0]])
    assert longest_travel(np.arange(10), 5, positions, 0.4) == 8  # 2.8 m: 7 spacings + 1
    assert longest_travel(np.array([3, 4, 5]), 5, positions, 0.4) == 1  # one place
    # a step longer than `gap` in index splits the runs: 0-2 (0.8 m) and 9 alone
    assert longest_travel(np.array([0, 1, 2, 9]), 5, positions, 0.4) == 3
    # keyframes 1 m apart count by their travel: 2.5 spacings, so 3 viewpoints
    assert longest_travel(np.array([0, 1]), 5, np.array([[0.0, 0], [1.0, 0]]), 0.4) == 3
    assert longest_travel(np.array([7]), 5, positions, 0.4) == 1
    assert longest_travel(np.zeros(0, np.int64), 5, positions, 0.4) == 0
    # every scan a viewpoint (spacing 0): the scans of the longest run, as longest_run
    assert longest_travel(np.array([0, 1, 2, 9]), 5, positions, 0.0) == 3
    assert longest_travel(np.array([3, 4, 5]), 5, positions, 0.0) == 3


def test_the_same_map_at_two_densities_gets_the_same_verdict(shared_data):
    # Intel rebuilt at its native rate (the density suite), every 2nd and every 5th scan.
    # At every 2nd scan two spurious regions once failed it: corridor scans of three later
    # visits whose submaps agreed on 0.37 m against the robot turning at the start, resting on
    # 3.3 m of shared surface (an object the start never saw); and ten viewpoints of a late
    # visit, turning within 2 m of travel, taken for a gross error.
    from pathlib import Path

    from map_consistency_ros.evaluation.density import Case, load
    checkout = Path(__file__).resolve().parents[3]
    for every in ('2', '5'):
        scans, _, _ = load(Case('intel-native', every, 'map'), shared_data, checkout)
        result = check_consistency(scans)
        assessment = explain(scans, result)
        assert assessment.consistent, (every, assessment.summary_line())
        assert not result.consistent  # the paper's test flags it: the verdict is the second stage
        if every == '2':
            # without the support it needs, the sliver's correction makes a region again
            bare = explain(scans, result, ExplanationSettings(min_region_support=0.0))
            assert any(region.registered for region in bare.misalignments)


def test_registrations_agree_on_where_they_put_the_points_not_on_how_far(shared_data):
    """Corrections of equal size in opposite directions disagree."""
    log = carmen.read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    scans = ScanSet.from_ranges(log.ranges[:6], log.laser_poses[:6], carmen.sensor_model(log))
    moments = PointMoments.of(scans)
    pairs = np.array([[0, 5]] * 6)
    tasks = np.arange(6)
    rows = np.arange(6)
    settings = ExplanationSettings()  # tolerance 0.1 m, three registrations
    east, west = np.array([0.2, 0.0, 0.0]), np.array([-0.2, 0.0, 0.0])
    split = np.array([east, east, east, west, west, west])
    assert agreeing_registrations(moments, rows, pairs, split, tasks, east, settings) == 3
    mostly = np.array([east, east, east, east + (0.0, 0.05, 0.0), east, west])
    assert agreeing_registrations(moments, rows, pairs, mostly, tasks, east, settings) == 5


def test_a_chain_bent_everywhere_is_distorted(intel):
    """Wrong constraints pulling a back-end apart bend the chain between consecutive scans:
    no pair-level misalignment needs to show for the map to be inconsistent."""
    log, _ = intel
    rng = np.random.default_rng(3)
    poses = log.laser_poses[:SCANS].copy()
    poses[:, :2] += rng.normal(0.0, 0.2, (SCANS, 2))
    poses[:, 2] += rng.normal(0.0, np.radians(2.0), SCANS)
    assessment = check_map(_map(intel, poses=poses))
    assert assessment.distorted and not assessment.consistent
    assert assessment.local_distortion > assessment.settings.misalignment_tolerance
    assert assessment.summary_line().startswith(
        'INCONSISTENT: locally distorted (consecutive scans disagree by ')
    # the paper's verdict is the paper's, distortion or not
    strict = explain(_map(intel, poses=poses), assessment.result, ExplanationSettings(strict=True))
    assert strict.consistent == assessment.result.consistent


def test_changed_places_join_points_through_neighbouring_cells():
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from map_consistency_ros.core.verdict import place_labels
    rng = np.random.default_rng(11)
    points = np.concatenate([rng.normal(size=(600, 2)) * 4.0, rng.normal(size=(80, 2)) * 0.2 + 30])
    labels = place_labels(points, 0.3)
    # Oracle: points whose cells touch (8-neighbourhood) are joined, transitively.
    cells = np.floor(points / 0.3).astype(int)
    touching = np.abs(cells[:, None] - cells[None]).max(axis=2) <= 1
    _, oracle = connected_components(coo_matrix(touching), directed=False)
    assert 10 < np.unique(oracle).size < 600
    same = labels[:, None] == labels[None]
    np.testing.assert_array_equal(same, oracle[:, None] == oracle[None])
    assert place_labels(points[:1], 0.3).tolist() == [0]


def _displaced_log(path, every, rotation_deg, shift_m, pivot_fraction, with_truth=False):
    """Viewpoints of every `every`-th record of a log, everything after a record turned and
    shifted rigidly (the same stretch of the building at any `every`); with_truth: also the
    viewpoints at their true poses."""
    log = carmen.read_carmen_log(path)
    poses = displace(log.laser_poses, int(pivot_fraction * log.scan_count), log.scan_count,
                     np.radians(rotation_deg), np.array([shift_m, 0.0]))
    rows = np.arange(0, log.scan_count, every)
    rows = rows[viewpoint_rows(poses[rows], 0.4, 0.4)]
    model = carmen.sensor_model(log, max_range=8.0)
    scans = ScanSet.from_ranges(log.ranges[rows], poses[rows], model)
    if not with_truth:
        return scans
    return scans, ScanSet.from_ranges(log.ranges[rows], log.laser_poses[rows], model)


def test_a_region_within_the_tolerance_is_minor_and_does_not_fail_the_map(shared_data):
    # Freiburg 079 every 10th scan, shifted 0.1 m after its middle: the region's own
    # correction moves its points by 0.109 m RMS, some of its pairs' corrections further
    scans = _displaced_log(shared_data / 'fr079' / 'freiburg-079-corrected.log.gz', 10, 0.0,
                           0.1, 0.5)
    result = check_consistency(scans)
    failing = explain(scans, result, ExplanationSettings(misalignment_tolerance=0.10))
    (region,) = failing.misalignments
    assert not failing.consistent and 0.10 < region.displacement < 0.11
    tolerant = explain(scans, result, ExplanationSettings(misalignment_tolerance=0.11))
    assert tolerant.class_counts()[MISALIGNED] > 0  # pairs beyond the tolerance ...
    (minor,) = tolerant.minor_misalignments  # ... but a region within it
    assert tolerant.consistent and not tolerant.misalignments
    assert minor.displacement == pytest.approx(region.displacement, abs=0.005)
    assert '1 minor region within it, largest 0.11 m' in tolerant.summary_line()
    assert not tolerant.misaligned_scans.any()


def test_a_turn_beyond_registration_at_a_seam_forms_a_region(shared_data):
    # Orebro turned 5 degrees after 60 % of its records: the later stretch revisits the start
    # 20 m from the seam, where the turn moved it 1.7 m, beyond what registration reaches;
    # its registrations snap onto other walls and agree, but their correction mends too
    # little: the region is a gross error, not "pairs misaligned and no region".
    scans = _displaced_log(shared_data / 'carmen_corrected_extra' / 'orebro-corrected.log.gz',
                           1, 5.0, 0.0, 0.6)
    assessment = explain(scans, check_consistency(scans))
    assert not assessment.consistent
    assert any(not region.registered and region.scans.min() >= 142
               and region.reference_scans.max() < 142 for region in assessment.misalignments)


def test_a_region_beyond_local_registration_reports_its_size(shared_data):
    # Freiburg 079 every 2nd scan turned 5 degrees after its middle: its submaps' corrections
    # exceed what local registration trusts (0.5 m), so the region is beyond it; registered as
    # one onto its reference scans it reports the displacement its end points really have.
    scans, truth = _displaced_log(shared_data / 'fr079' / 'freiburg-079-corrected.log.gz', 2,
                                  5.0, 0.0, 0.5, with_truth=True)
    result = check_consistency(scans)
    assessment = explain(scans, result)
    assert not assessment.consistent
    region = max(assessment.misalignments, key=lambda item: len(item.scans))
    moved = scans.endpoints[region.scans][scans.valid[region.scans]]
    true = truth.endpoints[region.scans][truth.valid[region.scans]]
    true_rms = float(np.sqrt(np.mean(np.sum((moved - true) ** 2, axis=1))))
    assert true_rms > 0.5
    assert region.registered and region.displacement == pytest.approx(true_rms, rel=0.1)
    assert abs(np.degrees(region.correction[2])) == pytest.approx(5.0, abs=0.5)
    assert np.isfinite(region.correction_std).all()
    # its submaps' own corrections were beyond what local registration trusts
    assert assessment.class_counts()[UNREGISTERED] > 0


@pytest.fixture(scope='module')
def orebro_seed_23(shared_data):
    """The whole-log suite's Orebro maps at seed 23, by name."""
    from map_consistency_ros.evaluation import whole_logs
    return {item.name: whole_logs.map_scans(item)[0]
            for item in whole_logs.build(shared_data, ['orebro'], 2, 23)}


def test_a_misalignment_hidden_among_changes_fails_the_map(orebro_seed_23):
    # Orebro shifted 0.3 m from scan 176 on: the shifted stretch meets earlier scans only at
    # the end revisit of the start (scans 226-236 against 0-3), a place whose furniture moved
    # between the visits. No correction makes those pairs pass, but three submap registrations
    # and the region registered whole agree on 0.36 m (an ICP-free grid search: 0.35 m).
    assessment = check_map(orebro_seed_23['orebro/shift 0.3 m #0'])
    assert not assessment.consistent, assessment.summary_line()
    (region,) = [item for item in assessment.misalignments if item.scans.min() >= 176]
    assert region.registered and region.reference_scans.max() <= 3
    assert 0.25 < region.displacement < 0.45
    pairs = assessment.result.pairs[assessment.explained_pairs]
    behind = np.isin(pairs[:, 1], region.scans) & np.isin(pairs[:, 0], region.reference_scans)
    assert (assessment.pair_classes[behind] == PAIR_CLASSES.index(MISALIGNED)).sum() \
        >= region.pairs


def test_among_changes_a_region_must_be_beyond_the_tolerance_by_more_than_its_spread(
        orebro_seed_23):
    # The corrected log itself is off at that revisit by 0.12 m RMS (registrations 0.12-0.14,
    # the grid search 0.12): beyond 0.10 by less than its registrations disagree. Judged on
    # their word alone, without the disagreement (significance 0.5: no margin), it would fail.
    scans = orebro_seed_23['orebro/corrected']
    result = check_consistency(scans)
    assert explain(scans, result).consistent
    bare = explain(scans, result, ExplanationSettings(significance=0.5))
    assert not bare.consistent
    region = max(bare.misalignments, key=lambda item: item.scans.min())
    assert region.scans.min() >= 220 and region.reference_scans.max() <= 3
    assert 0.10 < region.displacement < 0.15
