"""Map figures: the legend never hides data, whatever the map's size."""
import dataclasses

import numpy as np
import pytest

from map_consistency_ros.cli import plots
from map_consistency_ros.core.geometry import ScanSet, SensorModel
from map_consistency_ros.core.verdict import ChangedPlace, check_map


def _room_figure(scale: float, points: int):
    """Scans on a circle of radius 2 * `scale` metres (200 m across at 50), each seeing an arc
    at 3 * `scale`, with one changed place of `points` end points drawn on the map; the figure
    and its axes, drawn."""
    t = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    poses = np.stack([scale * 2 * np.cos(t), scale * 2 * np.sin(t), t + np.pi / 2], axis=1)
    ranges = np.full((len(poses), 180), 3.0 * scale)
    model = SensorModel(angle_min=-np.pi / 2, angle_increment=np.pi / 179,
                        max_range=10.0 * scale)
    scans = ScanSet.from_ranges(ranges, poses, model)
    assessment = check_map(scans)
    place = ChangedPlace(scans=np.array([0, 20]), x=4.0 * scale, y=4.0 * scale, points=points)
    assessment = dataclasses.replace(assessment, changes=(place,))
    figure, ax = plots.plt.subplots(figsize=(9, 9))
    plots.plot_map(ax, scans, assessment, 'room')
    figure.tight_layout()
    figure.canvas.draw()
    return figure, ax


@pytest.mark.parametrize('scale, points', [(1.0, 10), (50.0, 5000)])
def test_legend_symbols_have_one_size_and_the_legend_is_outside_the_map(scale, points):
    figure, ax = _room_figure(scale, points)
    try:
        legend = ax.get_legend()
        labels = [text.get_text() for text in legend.get_texts()]
        assert 'changed places' in labels and 'trajectory' in labels
        sizes = [handle.get_sizes() for handle in legend.legend_handles
                 if hasattr(handle, 'get_sizes')]
        assert sizes and all(list(size) == [plots.LEGEND_MARKER_AREA] for size in sizes)
        # the map's own symbol keeps its size by point count; only the legend's is fixed
        (changed,) = [item for item in ax.collections if item.get_label() == 'changed places']
        assert changed.get_sizes()[0] == pytest.approx(8.0 + 4.0 * np.sqrt(points))
        renderer = figure.canvas.get_renderer()
        box, axes_box = legend.get_window_extent(renderer), ax.get_window_extent(renderer)
        assert not box.overlaps(axes_box)
        assert box.y1 <= axes_box.y0 and box.y0 >= 0  # below the map, still on the figure
    finally:
        plots.plt.close(figure)
