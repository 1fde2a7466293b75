"""Figures: the map with inconsistent scans highlighted (as the paper's Fig. 1), each misaligned
region zoomed in, the failed pairs behind the verdict, the pairs' test values.

Every figure names its scans as the printed summary and the report do (the input's laser
records), numbers the regions as they do (#1 the region that fails the map), fits its text
(long lines wrapped to the width of their axes) and lists every mark in its legend."""
from __future__ import annotations

import textwrap
from collections.abc import Callable
from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402  (the backend must be chosen first)
import numpy as np  # noqa: E402
from matplotlib.collections import PathCollection  # noqa: E402
from matplotlib.transforms import ScaledTranslation  # noqa: E402
from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar  # noqa: E402

from map_consistency_ros.cli.report import region_text, scan_span  # noqa: E402
from map_consistency_ros.core.consistency import ConsistencyResult, statistics  # noqa: E402
from map_consistency_ros.core.geometry import ScanSet, point_distances  # noqa: E402
from map_consistency_ros.core.verdict import (  # noqa: E402
    Assessment, Misalignment, misaligned_endpoints, scan_names)
from map_consistency_ros.io.staging import staged  # noqa: E402

# An end point counts as visibly inconsistent this many pair scales inside the other polygon.
_HIGHLIGHT_SCALES = 3.0
# Drawing order: map, scans, changed places, misaligned end points, region numbers on top.
_Z_PLACES, _Z_DEEP, _Z_NUMBERS = 3, 4, 5


def wrapped(text: str, ax, fontsize: float) -> str:
    """Text broken into lines that fit the width of an axes (each line of `text` on its own).

    Parameters
    ----------
    text: the text; its own line breaks are kept.
    ax: the axes the text spans (a title's).
    fontsize: the text's size in points.

    Returns
    -------
    The text with line breaks where a line would be wider than the axes.
    """
    figure = ax.get_figure()
    inches = ax.get_position().width * figure.get_figwidth()
    # an average character of the default sans-serif font is about 0.6 em wide
    width = max(int(inches * 72.0 / (0.6 * fontsize)), 20)
    return '\n'.join(textwrap.fill(line, width) for line in text.split('\n'))


def title_name(source) -> str:
    """How a figure titles its input: the file's name, not its whole path.

    Parameters
    ----------
    source: the input's path, or any label.

    Returns
    -------
    The last part of the path ('' for none).
    """
    return Path(str(source)).name if source else ''


def plot_map(ax, scans: ScanSet, assessment: Assessment | None = None,
             title: str = '') -> None:
    """Draw all end points and the trajectory; then the misaligned regions (orange: the moved
    scans, purple: their reference scans, red: their inconsistent end points, #k: their numbers
    as printed) and the changed places (cyan circles, area by point count), as in the paper's
    Fig. 1.

    Parameters
    ----------
    ax: the matplotlib axes to draw on.
    scans: the map's scans, at the poses judged.
    assessment: both stages' verdict on `scans`; None: the map alone.
    title: the title (the input's file name), above the verdict's summary line.
    """
    valid_points = scans.endpoints[scans.valid]
    ax.scatter(valid_points[:, 0], valid_points[:, 1], s=0.05, c='0.35', linewidths=0,
               rasterized=True, label='end points')
    ax.plot(scans.sensor_poses[:, 0], scans.sensor_poses[:, 1], lw=0.5, c='tab:blue', alpha=0.6,
            label='trajectory')
    if assessment is not None:
        _plot_explanation(ax, scans, assessment)
        title = f'{title}\n{assessment.summary_line()}' if title else assessment.summary_line()
    ax.set_title(wrapped(title, ax, 8), fontsize=8)
    ax.set_aspect('equal')
    ax.set_xlabel('x [m]')
    ax.set_ylabel('y [m]')
    add_legend(ax)


# Area (points^2) of every scatter symbol in a legend: the map draws end points far smaller
# and changed places far larger (by point count), neither of which reads well in a legend.
LEGEND_MARKER_AREA = 16.0


def add_legend(ax) -> None:
    """The legend below the axes and their x label, outside them, so that it never hides
    data, in as many columns (at most 3) as fit the axes' width, with every scatter symbol
    at LEGEND_MARKER_AREA whatever its size on the map.

    Parameters
    ----------
    ax: the matplotlib axes whose labelled artists it lists; without any, no legend.
    """
    handles, labels = ax.get_legend_handles_labels()
    if not handles:
        return
    figure = ax.get_figure()
    # a fixed distance below the axes, whatever their height: below tick labels and x label
    anchor = ax.transAxes + ScaledTranslation(0.0, -_LEGEND_DROP_INCHES, figure.dpi_scale_trans)
    renderer = figure.canvas.get_renderer()
    for columns in range(min(len(handles), 3), 0, -1):
        legend = ax.legend(handles, labels, loc='upper center', bbox_to_anchor=(0.5, 0.0),
                           bbox_transform=anchor, ncol=columns, fontsize=6, frameon=True)
        if legend.get_window_extent(renderer).width <= ax.get_window_extent(renderer).width:
            break
    for handle in legend.legend_handles:
        if isinstance(handle, PathCollection):
            handle.set_sizes([LEGEND_MARKER_AREA])


_LEGEND_DROP_INCHES = 0.5


def _scan_points(scans: ScanSet, selected: np.ndarray) -> np.ndarray:
    return scans.endpoints[selected][scans.valid[selected]]


def region_anchor(scans: ScanSet, assessment: Assessment, region: Misalignment) -> np.ndarray:
    """Where a region's number goes on the map: the deep inconsistent end point of its
    strongest pairs nearest their median, where it fails (the median itself may lie in an
    empty room); its centroid where it has none.

    Parameters
    ----------
    scans: the scans the assessment was made on.
    assessment: the verdict.
    region: one of its regions.

    Returns
    -------
    (2,) metres.
    """
    deep = misaligned_endpoints(scans, assessment, max_pairs=50, min_depth=_HIGHLIGHT_SCALES,
                                region=region)
    if len(deep):
        return deep[np.argmin(np.hypot(*(deep - np.median(deep, axis=0)).T))]
    if np.all(np.isfinite(region.centroid)):
        return np.asarray(region.centroid, dtype=np.float64)
    return _scan_points(scans, region.scans).mean(axis=0)


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
    if assessment.changes:
        places = np.array([(place.x, place.y, place.points) for place in assessment.changes])
        ax.scatter(places[:, 0], places[:, 1], s=8.0 + 4.0 * np.sqrt(places[:, 2]),
                   facecolors='none', edgecolors='tab:cyan', linewidths=0.6, alpha=0.8,
                   zorder=_Z_PLACES, label='changed places')
    # above the changed places: a region's points must never hide under a circle
    deep = misaligned_endpoints(scans, assessment, min_depth=_HIGHLIGHT_SCALES)
    if len(deep):
        ax.scatter(deep[:, 0], deep[:, 1], s=2.0, c='red', linewidths=0, zorder=_Z_DEEP,
                   label='misaligned end points')
    if assessment.settings.strict:
        return
    for number, region in enumerate(assessment.misalignments, 1):
        # beside the region, joined by a line, so that the label hides none of its points
        ax.annotate(f'#{number}', xy=region_anchor(scans, assessment, region), xytext=(12, 12),
                    textcoords='offset points', fontsize=9, fontweight='bold', zorder=_Z_NUMBERS,
                    bbox=dict(boxstyle='round,pad=0.2', fc='white', ec='red', lw=0.8),
                    arrowprops=dict(arrowstyle='-', color='red', lw=0.8))
    if assessment.misalignments:
        ax.plot([], [], ls='none', marker='s', mfc='white', mec='red', ms=6,
                label='#k: misaligned region k, as printed')


def plot_statistics(ax, result: ConsistencyResult) -> None:
    """Histogram of the pairs' test values (standardized inconsistency, the paper's Psi) over
    the tested pairs, with the pairwise test's threshold.

    Parameters
    ----------
    ax: the matplotlib axes to draw on.
    result: the consistency result the summary counts (every tested pair); the threshold is
        that of its parameters' alpha.
    """
    psi = result.statistic[result.tested]
    threshold = statistics.normal_quantile(result.parameters.alpha)
    if psi.size:
        upper = max(float(np.max(psi)), threshold) + 1.0
        bins = np.linspace(min(float(np.min(psi)), -5.0), upper, 80)
        ax.hist(psi, bins=bins, color='tab:blue', alpha=0.8, label='tested pairs')
        ax.set_yscale('log')
    ax.axvline(threshold, color='red', lw=1,
               label=f'a pair fails above {threshold:.2f} (level {result.parameters.alpha:g})')
    ax.set_xlabel("pair's standardized inconsistency (test value)")
    ax.set_ylabel('pairs')
    ax.set_title(statistics_title(result), fontsize=9)
    ax.legend(fontsize=7)


def statistics_title(result: ConsistencyResult) -> str:
    """The statistics figure's title: the counts the printed summary and the report give.

    Parameters
    ----------
    result: the consistency result.

    Returns
    -------
    e.g. '65 of 5644 tested pairs failed'.
    """
    return f'{result.failed_pair_count} of {result.tested_pair_count} tested pairs failed'


def plot_pair(ax, scans: ScanSet, result: ConsistencyResult, index: int,
              scan_ids: np.ndarray | None = None, heading: str = '') -> None:
    """Two scans of one pair: the free space each saw, its end points, and the end points
    deep inside the other's free space (red).

    Parameters
    ----------
    ax: the matplotlib axes to draw on (8 m square around the overlap).
    scans: the scans tested.
    result: their consistency result.
    index: the pair's row in result.pairs.
    scan_ids: (N,) names of the scans (the input's laser records); None: their indices.
    heading: the title's first line (what the pair is to the verdict); '' for none.
    """
    ids = scan_names(result, scan_ids)
    i, j = (int(value) for value in result.pairs[index])
    of_j_in_i, of_i_in_j = point_distances(scans, i, j)
    limit = _HIGHLIGHT_SCALES * max(result.scales[i], result.scales[j])
    deep_points = []
    for scan, colour, inside in ((i, 'tab:blue', of_i_in_j), (j, 'tab:green', of_j_in_i)):
        sensor = scans.sensor_poses[scan, :2]
        outline = np.vstack([sensor, scans.endpoints[scan], sensor])
        ax.fill(outline[:, 0], outline[:, 1], color=colour, alpha=0.08, linewidth=0,
                label=f'free space seen by scan {ids[scan]}')
        valid = scans.valid[scan]
        ax.scatter(scans.endpoints[scan][valid, 0], scans.endpoints[scan][valid, 1], s=2,
                   c=colour, label=f'end points of scan {ids[scan]}')
        deep_points.append(scans.endpoints[scan][inside > limit])
    deep = np.vstack(deep_points)
    if len(deep):
        ax.scatter(deep[:, 0], deep[:, 1], s=8, c='red', zorder=_Z_DEEP,
                   label="end points deep in the other's free space")
    inside_points = np.vstack([scans.endpoints[j][of_j_in_i > 0],
                               scans.endpoints[i][of_i_in_j > 0]])
    centre = inside_points.mean(axis=0) if len(inside_points) else scans.sensor_poses[i, :2]
    ax.set_xlim(centre[0] - 4, centre[0] + 4)
    ax.set_ylim(centre[1] - 4, centre[1] + 4)
    ax.set_aspect('equal')
    ax.set_xlabel('x [m]')
    ax.set_ylabel('y [m]')
    count = int(result.point_count[index])
    threshold = statistics.normal_quantile(result.parameters.alpha)
    lines = [heading] if heading else []
    lines.append(f'scans {ids[i]} and {ids[j]}: {count} end points inside the other\'s free '
                 f'space, {100 * result.distance_sum[index] / max(count, 1):.1f} cm deep on '
                 f'average; test value {result.statistic[index]:.1f} (fails above '
                 f'{threshold:.2f}); noise scales {100 * result.scales[i]:.1f} and '
                 f'{100 * result.scales[j]:.1f} cm')
    ax.set_title(wrapped('\n'.join(lines), ax, 8), fontsize=8)
    add_legend(ax)


def explained_pairs(assessment: Assessment, count: int = 3) -> list[tuple[int, str]]:
    """The failed pairs `--explain` shows: those of the region that fails the map first (#1,
    its strongest pairs), then the strongest other failed pairs.

    Parameters
    ----------
    assessment: the verdict.
    count: the most pairs of each kind.

    Returns
    -------
    [(row of result.pairs, what the pair is to the verdict, e.g. 'region #1 (fails the map),
    a pair classed misaligned')].
    """
    result = assessment.result
    shown = []
    if assessment.misalignments and not assessment.settings.strict:
        rows = assessment.region_pairs(assessment.misalignments[0])[:count]
        shown += [(int(row), f'region #1 (fails the map), a pair classed {name}')
                  for row, name in zip(rows, assessment.pair_class(rows))]
    taken = {row for row, _ in shown}
    order = np.argsort(-np.where(result.failed, result.statistic, -np.inf), kind='stable')
    others = [int(row) for row in order[:count + len(taken)]
              if result.failed[row] and int(row) not in taken][:count]
    shown += [(row, f'{"another" if taken else "a"} strong failed pair, classed {name}')
              for row, name in zip(others, assessment.pair_class(np.array(others, dtype=int)))]
    return shown


def save_pairs_figure(path: str | Path, scans: ScanSet, assessment: Assessment,
                      scan_ids: np.ndarray | None = None, count: int = 3) -> None:
    """Write the failed pairs of `explained_pairs` as a PNG: the region that fails the map
    (its pairs on the first row), then the strongest other failed pairs, each zoomed in.

    Parameters
    ----------
    path: the PNG; its folder is created.
    scans: the scans tested.
    assessment: their verdict; without a failed pair, one empty panel says so.
    scan_ids: (N,) names of the scans (the input's laser records); None: their indices.
    count: the most pairs of each kind.
    """
    shown = explained_pairs(assessment, count)
    region = [item for item in shown if item[1].startswith('region #')]
    rows = [region, shown[len(region):]] if region else [shown]
    rows = [row for row in rows if row] or [[]]
    columns = max(max(len(row) for row in rows), 1)
    figure, axes = plt.subplots(len(rows), columns, figsize=(5.5 * columns, 6.5 * len(rows)),
                                squeeze=False)
    for axes_row, row in zip(axes, rows):
        for ax, (index, heading) in zip(axes_row, row):
            plot_pair(ax, scans, assessment.result, index, scan_ids, heading)
        for ax in axes_row[len(row):]:
            ax.set_axis_off()
    if not shown:
        axes[0, 0].set_axis_on()
        axes[0, 0].set_title('no failed pair')
    lay_out(figure)
    save_figure(figure, path)


def region_figure_paths(path: str | Path, count: int) -> list[Path]:
    """Where the zoomed figures of the misaligned regions go, beside the map figure.

    Parameters
    ----------
    path: the map figure (--plot), e.g. out/map.png.
    count: the number of misaligned regions.

    Returns
    -------
    [out/map_region1.png, out/map_region2.png, ...], one per region, numbered as printed.
    """
    path = Path(path)
    return [path.with_name(f'{path.stem}_region{number}{path.suffix}')
            for number in range(1, count + 1)]


# A region's view reaches this far beyond its deep end points, and is at least this wide.
_REGION_MARGIN, _REGION_MIN_VIEW = 1.5, 6.0


def plot_region(axes, scans: ScanSet, assessment: Assessment, number: int,
                scan_ids: np.ndarray | None = None) -> None:
    """One misaligned region, zoomed in where it fails: as mapped (its scans orange, its
    reference scans purple, its deep inconsistent end points red), and with its correction
    applied, each with a scale bar.

    Parameters
    ----------
    axes: matplotlib axes: as mapped, then corrected (a region beyond local registration
        has no correction: one axes for it suffices; a second one says so).
    scans: the scans the assessment was made on.
    assessment: the verdict.
    number: the region's number as printed (1 for assessment.misalignments[0]).
    scan_ids: (N,) names of the scans; None: their indices.
    """
    region = assessment.misalignments[number - 1]
    ids = scan_names(assessment.result, scan_ids)
    deep = misaligned_endpoints(scans, assessment, max_pairs=200, min_depth=_HIGHLIGHT_SCALES,
                                region=region)
    view_points = deep if len(deep) else _scan_points(scans, region.scans)
    if not len(view_points):  # scans that hit nothing: where they were taken
        view_points = scans.sensor_poses[region.scans, :2]
    low, high = np.percentile(view_points, [5, 95], axis=0)
    centre = (low + high) / 2.0
    half = max(float(np.max(high - low)) / 2.0 + _REGION_MARGIN, _REGION_MIN_VIEW / 2.0)
    corrected = np.all(np.isfinite(region.correction))
    moved = scans
    if corrected:
        transforms = np.zeros((scans.scan_count, 3))  # the others stay where they are
        transforms[region.scans] = region.correction
        moved = scans.moved(np.arange(scans.scan_count), transforms)
    panels = (('as mapped', scans, True), ('with its correction', moved, False))
    for ax, (name, placed, show_deep) in zip(axes, panels):
        if name != 'as mapped' and not corrected:
            ax.set_axis_off()
            ax.text(0.5, 0.5, wrapped('beyond local registration: no correction measured',
                                      ax, 9), ha='center', va='center', fontsize=9,
                    transform=ax.transAxes)
            continue
        others = np.ones(scans.scan_count, dtype=bool)
        others[region.scans] = others[region.reference_scans] = False
        for selected, colour, size, label in (
                (others, '0.6', 0.3, 'other scans'),
                (region.reference_scans, 'tab:purple', 1.0,
                 f'reference scans ({scan_span(ids[region.reference_scans])})'),
                (region.scans, 'tab:orange', 1.0,
                 f'region #{number} ({scan_span(ids[region.scans])})')):
            points = _scan_points(placed, selected)
            inside = np.all(np.abs(points - centre) <= half, axis=1)
            ax.scatter(points[inside, 0], points[inside, 1], s=size, c=colour, linewidths=0,
                       rasterized=True, label=label)
        if show_deep and len(deep):
            ax.scatter(deep[:, 0], deep[:, 1], s=3, c='red', linewidths=0, zorder=_Z_DEEP,
                       label="end points deep in the other's free space")
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] - half, centre[1] + half)
        ax.set_aspect('equal')
        ax.set_xlabel('x [m]')
        ax.set_ylabel('y [m]')
        add_scale_bar(ax, 2.0 * half)
        heading = (f'region #{number} as mapped: {region_text(region, ids)}'
                   if name == 'as mapped' else
                   f'region #{number} with its correction applied: its scans moved back '
                   'onto its reference scans')
        ax.set_title(wrapped(heading, ax, 8), fontsize=8)
        add_legend(ax)


def add_scale_bar(ax, width: float) -> None:
    """A scale bar in the lower right corner of a map's axes: a round length near a fifth of
    the view.

    Parameters
    ----------
    ax: the axes (metres on both axes).
    width: the width of the view, metres.
    """
    target = width / 5.0
    length = max((step * 10.0 ** exponent for exponent in range(-2, 4) for step in (1, 2, 5)
                  if step * 10.0 ** exponent <= target), default=0.01)
    ax.add_artist(AnchoredSizeBar(ax.transData, length, f'{length:g} m', 'lower right',
                                  pad=0.4, frameon=True, size_vertical=0, fontproperties={
                                      'size': 7}))


def save_region_figures(path: str | Path, scans: ScanSet, assessment: Assessment,
                        scan_ids: np.ndarray | None = None,
                        place: Callable[[Path], Path] | None = None) -> list[Path]:
    """Write one zoomed figure per misaligned region beside the map figure (`plot_region`,
    paths from `region_figure_paths`).

    Parameters
    ----------
    path: the map figure (--plot).
    scans: the scans the assessment was made on.
    assessment: the verdict; a strict verdict has no regions, and none are written.
    scan_ids: (N,) names of the scans; None: their indices.
    place: where a figure is written for its final path (StagedOutputs.path, so that they
        appear with the caller's other outputs); None: at that path.

    Returns
    -------
    The figures written, region #1 first.
    """
    if assessment.settings.strict:
        return []
    paths = region_figure_paths(path, len(assessment.misalignments))
    for (number, target), region in zip(enumerate(paths, 1), assessment.misalignments):
        panels = 2 if np.all(np.isfinite(region.correction)) else 1
        figure, axes = plt.subplots(1, panels, figsize=(6 * panels, 7.5), squeeze=False)
        plot_region(axes[0], scans, assessment, number, scan_ids)
        lay_out(figure)
        save_figure(figure, target if place is None else place(target))
    return paths


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
    lay_out(figure)
    save_figure(figure, path)


def save_statistics_figure(path: str | Path, result: ConsistencyResult) -> None:
    """Write the histogram of the pairs' test values (`plot_statistics`) as a PNG.

    Parameters
    ----------
    path: the PNG; its folder is created.
    result: the consistency result.
    """
    figure, ax = plt.subplots(figsize=(7, 4))
    plot_statistics(ax, result)
    lay_out(figure)
    save_figure(figure, path)


def lay_out(figure) -> None:
    """Lay a figure out on its drawn extents: titles, labels and legends outside the axes
    within the figure, whatever the axes' aspect (a layout before the first drawing places
    equal-aspect axes where they are not drawn, and cuts their legends and titles).

    Parameters
    ----------
    figure: the matplotlib figure, drawn into; save_figure lays it out once more as it is.
    """
    figure.canvas.draw()
    figure.tight_layout()


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
