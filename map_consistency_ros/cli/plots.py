"""Figures: the map with inconsistent scans highlighted (as the paper's Fig. 1), Psi statistics."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402  (the backend must be chosen first)
import numpy as np  # noqa: E402
from matplotlib.collections import PathCollection  # noqa: E402

from map_consistency_ros.core.consistency import ConsistencyResult, statistics  # noqa: E402
from map_consistency_ros.core.geometry import ScanSet, point_distances  # noqa: E402
from map_consistency_ros.core.verdict import (  # noqa: E402
    Assessment, misaligned_endpoints)
from map_consistency_ros.io.staging import staged  # noqa: E402

# An end point counts as visibly inconsistent this many pair scales inside the other polygon.
_HIGHLIGHT_SCALES = 3.0


def plot_map(ax, scans: ScanSet, assessment: Assessment | None = None, title: str = '') -> None:
    """Draw all end points and the trajectory; then the misaligned regions (orange: the moved
    scans, purple: their reference scans, red: their inconsistent end points) and the changed
    places (blue circles, area by point count), as in the paper's Fig. 1.

    Parameters
    ----------
    ax: the matplotlib axes to draw on.
    scans: the map's scans, at the poses judged.
    assessment: both stages' verdict on `scans`; None: the map alone.
    title: the title, above the verdict's summary line.
    """
    valid_points = scans.endpoints[scans.valid]
    ax.scatter(valid_points[:, 0], valid_points[:, 1], s=0.05, c='0.35', linewidths=0,
               rasterized=True)
    ax.plot(scans.sensor_poses[:, 0], scans.sensor_poses[:, 1], lw=0.5, c='tab:blue', alpha=0.6,
            label='trajectory')
    if assessment is not None:
        _plot_explanation(ax, scans, assessment)
        title = f'{title}\n{assessment.summary_line()}' if title else assessment.summary_line()
    ax.set_title(title, fontsize=8)
    ax.set_aspect('equal')
    ax.set_xlabel('x [m]')
    ax.set_ylabel('y [m]')
    add_legend(ax)


# Area (points^2) of every scatter symbol in a legend: the map draws end points far smaller
# and changed places far larger (by point count), neither of which reads well in a legend.
LEGEND_MARKER_AREA = 16.0


def add_legend(ax) -> None:
    """The legend below the axes, outside them, so that it never hides data, with every
    scatter symbol at LEGEND_MARKER_AREA whatever its size on the map.

    Parameters
    ----------
    ax: the matplotlib axes whose labelled artists it lists; without any, no legend.
    """
    handles, labels = ax.get_legend_handles_labels()
    if not handles:
        return
    legend = ax.legend(handles, labels, loc='upper center', bbox_to_anchor=(0.5, -0.07),
                       ncol=min(len(handles), 3), fontsize=6, frameon=True)
    for handle in legend.legend_handles:
        if isinstance(handle, PathCollection):
            handle.set_sizes([LEGEND_MARKER_AREA])


def _scan_points(scans: ScanSet, selected: np.ndarray) -> np.ndarray:
    return scans.endpoints[selected][scans.valid[selected]]


def _plot_explanation(ax, scans: ScanSet, assessment: Assessment) -> None:
    moved = np.zeros(scans.scan_count, dtype=bool)
    reference = np.zeros(scans.scan_count, dtype=bool)
    for region in assessment.misalignments:
        moved[region.scans] = True
        reference[region.reference_scans] = True
    if assessment.settings.strict:
        moved = assessment.result.inconsistent
    for selected, colour, label in ((reference & ~moved, 'tab:purple', 'reference scans'),
                                    (moved, 'tab:orange', 'misaligned scans')):
        if selected.any():
            points = _scan_points(scans, selected)
            ax.scatter(points[:, 0], points[:, 1], s=0.3, c=colour, linewidths=0,
                       rasterized=True, label=label)
    deep = misaligned_endpoints(scans, assessment, min_depth=_HIGHLIGHT_SCALES)
    if len(deep):
        ax.scatter(deep[:, 0], deep[:, 1], s=2.0, c='red', linewidths=0,
                   label='misaligned end points')
    if assessment.changes:
        places = np.array([(place.x, place.y, place.points) for place in assessment.changes])
        ax.scatter(places[:, 0], places[:, 1], s=8.0 + 4.0 * np.sqrt(places[:, 2]), facecolors='none',
                   edgecolors='tab:cyan', linewidths=0.8, label='changed places')


def plot_statistics(ax, result: ConsistencyResult) -> None:
    """Histogram of Psi over the tested pairs, with the pairwise test's threshold.

    Parameters
    ----------
    ax: the matplotlib axes to draw on.
    result: the consistency result; the threshold is that of its parameters' alpha.
    """
    psi = result.statistic[result.tested]
    threshold = statistics.normal_quantile(result.parameters.alpha)
    if psi.size:
        upper = max(float(np.max(psi)), threshold) + 1.0
        bins = np.linspace(min(float(np.min(psi)), -5.0), upper, 80)
        ax.hist(psi, bins=bins, color='tab:blue', alpha=0.8, label='tested pairs')
        ax.set_yscale('log')
    ax.axvline(threshold, color='red', lw=1,
               label=f'F^-1(1 - alpha) = {threshold:.2f}')
    ax.set_xlabel('standardized inconsistency Psi_ij')
    ax.set_ylabel('pairs')
    ax.set_title(f'{result.failed_pair_count} of {result.tested_pair_count} tested pairs failed',
                 fontsize=9)
    ax.legend(fontsize=7)


def plot_pair(ax, scans: ScanSet, result: ConsistencyResult, index: int) -> None:
    """Two scans of one pair: free space, end points, and the end points deep in the other.

    Parameters
    ----------
    ax: the matplotlib axes to draw on (8 m square around the overlap).
    scans: the scans tested.
    result: their consistency result.
    index: the pair's row in result.pairs.
    """
    i, j = (int(value) for value in result.pairs[index])
    of_j_in_i, of_i_in_j = point_distances(scans, i, j)
    limit = _HIGHLIGHT_SCALES * max(result.scales[i], result.scales[j])
    for scan, colour, inside in ((i, 'tab:blue', of_i_in_j), (j, 'tab:green', of_j_in_i)):
        sensor = scans.sensor_poses[scan, :2]
        outline = np.vstack([sensor, scans.endpoints[scan], sensor])
        ax.fill(outline[:, 0], outline[:, 1], color=colour, alpha=0.08, linewidth=0)
        valid = scans.valid[scan]
        ax.scatter(scans.endpoints[scan][valid, 0], scans.endpoints[scan][valid, 1], s=2,
                   c=colour, label=f'scan {scan}')
        deep = scans.endpoints[scan][inside > limit]
        ax.scatter(deep[:, 0], deep[:, 1], s=8, c='red')
    inside_points = np.vstack([scans.endpoints[j][of_j_in_i > 0], scans.endpoints[i][of_i_in_j > 0]])
    centre = inside_points.mean(axis=0) if len(inside_points) else scans.sensor_poses[i, :2]
    ax.set_xlim(centre[0] - 4, centre[0] + 4)
    ax.set_ylim(centre[1] - 4, centre[1] + 4)
    ax.set_aspect('equal')
    ax.legend(fontsize=7)
    count = result.point_count[index]
    ax.set_title(f'pair ({i}, {j}): Psi = {result.statistic[index]:.1f}, n = {count}, '
                 f'mean distance {100 * result.distance_sum[index] / max(count, 1):.1f} cm\n'
                 f's_i = {100 * result.scales[i]:.1f} cm, s_j = {100 * result.scales[j]:.1f} cm',
                 fontsize=8)


def save_pairs_figure(path: str | Path, scans: ScanSet, result: ConsistencyResult,
                      count: int = 3) -> None:
    """Write the `count` failed pairs with the largest Psi, side by side (red: deep end
    points), as a PNG.

    Parameters
    ----------
    path: the PNG; its folder is created.
    scans: the scans tested.
    result: their consistency result; without a failed pair, one empty panel says so.
    count: the most pairs shown.
    """
    strongest = np.argsort(-np.where(result.failed, result.statistic, -np.inf))[:count]
    strongest = [index for index in strongest if result.failed[index]]
    figure, axes = plt.subplots(1, max(len(strongest), 1), figsize=(5 * max(len(strongest), 1), 5),
                                squeeze=False)
    for ax, index in zip(axes[0], strongest):
        plot_pair(ax, scans, result, int(index))
    if not strongest:
        axes[0, 0].set_title('no failed pair')
    save_figure(figure, path)


def save_map_figure(path: str | Path, scans: ScanSet, assessment: Assessment | None,
                    title: str = '') -> None:
    """Write the map figure (`plot_map`) as a PNG.

    Parameters
    ----------
    path: the PNG; its folder is created.
    scans, assessment, title: as `plot_map` takes them.
    """
    figure, ax = plt.subplots(figsize=(9, 9))
    plot_map(ax, scans, assessment, title)
    save_figure(figure, path)


def save_statistics_figure(path: str | Path, result: ConsistencyResult) -> None:
    """Write the Psi histogram (`plot_statistics`) as a PNG.

    Parameters
    ----------
    path: the PNG; its folder is created.
    result: the consistency result.
    """
    figure, ax = plt.subplots(figsize=(7, 4))
    plot_statistics(ax, result)
    save_figure(figure, path)


def save_figure(figure, path: str | Path) -> None:
    """Write `figure` at 150 dpi, laid out tight, and close it.

    Parameters
    ----------
    figure: the matplotlib figure.
    path: the image file (PNG by its suffix); its folder is created. Written whole or not at
        all (io/staging.py).
    """
    try:
        figure.tight_layout()
        with staged(path) as target:
            figure.savefig(target, dpi=150)
    finally:
        plt.close(figure)
