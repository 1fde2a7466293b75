"""The parameters of localization mode that mapping mode does not have (docs/localization.md
gives each default's reason). The paper's test itself (alpha, the failure probability, the
binomial level, the local window of the scales, trimming, min_points, the default and least
scale, the fold's depth and disagreement for the frozen estimate) keeps its one definition in
ConsistencyParameters."""
from __future__ import annotations

from dataclasses import dataclass

from map_consistency_ros.core.parameters import Settings, parameter


@dataclass(frozen=True)
class LocalizationSettings(Settings):
    """Windows, what can be judged, and the second stage's rule for a mislocalization."""

    max_unjudged: float = parameter(
        0.5, 'a live scan with more of its valid beams ending in unknown space or off the map '
        'is not judged', '', (0.0, 1.0))
    resolution_scale: float = parameter(
        0.5, 'least scale s_i of a scan against the map, in map cells (the cells quantize '
        'every distance)', 'cells', (0.0, 10.0))
    scale_metres: float = parameter(
        2.0, "the live scales s_i (eq. 10) come from pairs of temporally adjacent live scans at "
        "most this much travel apart (and within the test's local window)", 'm', (0.0, 1000.0))
    window_metres: float = parameter(
        5.0, 'the cascaded test counts the failed scans of the last this many metres of '
        'travel (or window_seconds, whichever is reached first)', 'm', (0.1, 1000.0))
    window_seconds: float = parameter(
        30.0, 'the cascaded test counts the failed scans of the last this many seconds (or '
        'window_metres, whichever is reached first)', 's', (0.1, 100_000.0))
    submap_metres: float = parameter(
        3.0, 'consecutive live scans registered onto the map as one submap span this much '
        'travel (or submap_seconds, whichever is reached first)', 'm', (0.1, 1000.0))
    submap_seconds: float = parameter(
        15.0, 'consecutive live scans registered onto the map as one submap span this long '
        '(or submap_metres, whichever is reached first)', 's', (0.1, 100_000.0))
    gates: tuple = parameter(
        (1.2, 0.6, 0.3, 0.15), 'association gates of the registration onto the map, coarse to '
        'fine (the coarsest bounds the error that can be found)', 'm')
    trim: float = parameter(
        0.1, "share of the largest residuals each registration step leaves out (mapping "
        "mode's 0.3 drops the walls across a sideways error against a whole map)", '',
        (0.0, 0.89))
    search_step: float = parameter(
        0.15, "spacing of the shifts of the coarse search that seeds a registration the "
        "estimate's own start does not bring home", 'm', (0.01, 10.0))
    search_step_deg: float = parameter(
        2.5, 'spacing of the rotations of the coarse search', 'deg', (0.1, 90.0))
    max_translation: float = parameter(
        1.5, 'largest correction at the robot trusted as a mislocalization', 'm', (0.01, 100.0))
    max_rotation_deg: float = parameter(
        15.0, 'largest heading correction trusted as a mislocalization', 'deg', (0.1, 180.0))
    min_position_error: float = parameter(
        0.15, 'a correction moving the robot less than this (and turning it less than '
        'min_heading_error_deg) is no mislocalization', 'm', (0.0, 100.0))
    min_heading_error_deg: float = parameter(
        1.5, 'a correction turning the robot less than this (and moving it less than '
        'min_position_error) is no mislocalization', 'deg', (0.0, 180.0))
    significance: float = parameter(
        0.001, 'level of the chi-square test that a correction differs from zero', '',
        (1e-12, 0.5))
    mend_fraction: float = parameter(
        0.5, "share of a submap's failed scans that must pass after its correction (or the "
        'submap passes the cascaded test)', '', (0.0, 1.0))
    mend_ratio: float = parameter(
        0.1, "a correction also mends a submap when its mean Psi falls to this share of what "
        'it was', '', (0.0, 1.0))
    min_agreeing: int = parameter(
        2, 'overlapping or adjacent submaps whose corrections must agree on a mislocalization',
        'submaps', (1, 1000))
    agreement_metres: float = parameter(
        0.15, 'two corrections agree when they place the robot this close', 'm', (0.0, 100.0))
    agreement_deg: float = parameter(
        2.0, 'two corrections agree when their headings differ less than this', 'deg',
        (0.0, 180.0))
    change_depth: float = parameter(
        3.0, 'end points and map obstacles this many scales s_i deep mark a change', 'scales',
        (0.0, 100.0))
    change_cell: float = parameter(
        0.5, 'changed points closer than this form one place', 'm', (0.01, 100.0))
    max_change_extent: float = parameter(
        3.0, 'a changed place spans at most this (larger connected deep areas are split into '
        'tiles of this size, each reported at its centroid)', 'm', (0.1, 1000.0))
    min_change_points: int = parameter(
        50, 'deep points a changed place must hold, over the scans of its stretch (a person '
        'passing one scan leaves a few tens)', 'points', (1, 100_000))
    min_frozen_changes: int = parameter(
        3, 'changes of scene at one estimated pose that make a frozen estimate', '',
        (1, 100_000))

    def __post_init__(self) -> None:
        super().__post_init__()
        gates = tuple(float(gate) for gate in self.gates)
        if not gates or any(not gate > 0.0 for gate in gates) or list(gates) != sorted(
                gates, reverse=True):
            raise ValueError(f'gates must be positive metres shrinking from coarse to fine, '
                             f'got {self.gates}')
        object.__setattr__(self, 'gates', gates)
