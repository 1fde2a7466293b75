"""Map figures: the legend never hides data, whatever the map's size."""
import dataclasses

from pathlib import Path

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


def _texts_outside(figure) -> list[str]:
    """The visible texts of a figure, laid out as save_figure lays it out, that reach beyond
    the figure's edges (clipped in the PNG)."""
    from matplotlib.text import Text
    figure.tight_layout()
    figure.canvas.draw()
    renderer, box = figure.canvas.get_renderer(), figure.bbox
    # everything drawn (tick labels only of the ticks in view) within the figure
    drawn = figure.get_tightbbox(renderer)
    width, height = figure.get_size_inches()
    outside = ([] if drawn.x0 >= -0.01 and drawn.y0 >= -0.01 and drawn.x1 <= width + 0.01
               and drawn.y1 <= height + 0.01 else [f'drawn extent {drawn}'])
    ticks = {id(label) for ax in figure.axes for axis in (ax.xaxis, ax.yaxis)
             for label in axis.get_ticklabels(which='both')}
    for text in figure.findobj(Text):
        if not text.get_visible() or not text.get_text().strip() or id(text) in ticks:
            continue
        extent = text.get_window_extent(renderer)
        if (extent.x0 < box.x0 - 1 or extent.x1 > box.x1 + 1 or extent.y0 < box.y0 - 1
                or extent.y1 > box.y1 + 1):
            outside.append(text.get_text())
    return outside


def _unlisted(ax) -> set[str]:
    """Labels of an axes' marks (points, lines, shaded areas) missing from its legend."""
    legend = ax.get_legend()
    listed = {text.get_text() for text in legend.get_texts()} if legend else set()
    labels = {artist.get_label() for artist in (*ax.collections, *ax.lines, *ax.patches)
              if not artist.get_label().startswith('_')}
    return labels - listed


@pytest.fixture
def drawn_figures(monkeypatch):
    """The figures save_figure is given, with their texts outside the figure and their marks
    missing from the legends, checked as they are saved."""
    figures = []
    save_figure = plots.save_figure

    def checked(figure, path):
        figures.append({'path': path, 'outside': _texts_outside(figure),
                        'unlisted': [_unlisted(ax) for ax in figure.axes],
                        'titles': [ax.get_title() for ax in figure.axes],
                        'texts': [text.get_text() for ax in figure.axes for text in ax.texts]})
        save_figure(figure, path)

    monkeypatch.setattr(plots, 'save_figure', checked)
    return figures


def test_check_figures_fit_their_text_and_list_every_mark(displaced_room_log, drawn_figures,
                                                          tmp_path, capsys):
    from map_consistency_ros.cli.main import main
    path = displaced_room_log(name=f'a_room_with_a_rather_long_file_name_{"x" * 60}.log')
    code = main(['check', str(path), '--quiet', '--viewpoint-spacing', '0', '--viewpoint-turn',
                 '0', '--plot', str(tmp_path / 'map.png'), '--explain',
                 str(tmp_path / 'pairs.png')])
    out = capsys.readouterr().out
    assert code == 1
    # the region zoomed in beside the map, named as printed (drawn in a staging folder, then
    # put in place with the other outputs)
    names = ['map.png', 'map_region1.png', 'pairs.png']
    assert [Path(figure['path']).name for figure in drawn_figures] == names
    assert sorted(path.name for path in tmp_path.iterdir() if path.suffix == '.png') == names
    assert f'region #1 figure      {tmp_path / "map_region1.png"}' in out
    for figure in drawn_figures:
        assert figure['outside'] == [], figure['path']
        assert all(not missing for missing in figure['unlisted']), figure['path']
        for title in figure['titles']:  # plain words, not the paper's symbols
            assert not any(symbol in title for symbol in ('Psi', 's_i', 'n = '))
    overview, region, pairs = drawn_figures
    assert overview['titles'][0].startswith('a_room_with') and str(tmp_path) not in \
        overview['titles'][0]
    assert '#1' in overview['texts']  # the region's number drawn on the map
    assert [title.split(':')[0] for title in region['titles']] == [
        'region #1 as mapped', 'region #1 with its correction applied']
    assert pairs['titles'][0].startswith('region #1 (fails the map)')


def test_side_by_side_maps_keep_their_titles_apart():
    """tune --maps-plot draws two maps side by side: their long titles wrap, never overlap."""
    t = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    poses = np.stack([2 * np.cos(t), 2 * np.sin(t), t + np.pi / 2], axis=1)
    model = SensorModel(angle_min=-np.pi / 2, angle_increment=np.pi / 179, max_range=10.0)
    scans = ScanSet.from_ranges(np.full((40, 180), 3.0), poses, model)
    assessment = check_map(scans)
    figure, axes = plots.plt.subplots(1, 2, figsize=(14, 7))
    try:
        for ax, title in zip(axes, ('Phi = 1', 'Phi* = 16')):
            plots.plot_map(ax, scans, assessment, f'{title} {"on a long file name " * 8}')
        plots.lay_out(figure)  # as tune's _save_maps, before save_figure
        assert _texts_outside(figure) == []
        renderer = figure.canvas.get_renderer()
        first, second = (ax.title.get_window_extent(renderer) for ax in axes)
        assert not first.overlaps(second)
    finally:
        plots.plt.close(figure)
