"""nav2 map_server maps and OccupancyGrid message fields -> OccupancyGrid: handmade maps whose
cells are known pixel by pixel, round trips through the writer, and every bad input."""
import math

import numpy as np
import pytest

from map_consistency_ros.core.localization import FREE, OCCUPIED, UNKNOWN, OccupancyGrid
from map_consistency_ros.io.errors import InputError
from map_consistency_ros.io.occupancy_map import (grid_from_message_fields,
                                                  message_fields_from_grid, read_map_image,
                                                  read_occupancy_map, write_occupancy_map)

YAML = ('image: {image}\nmode: {mode}\nresolution: 0.05\norigin: [-1.5, 2.0, 0.0]\n'
        'negate: {negate}\noccupied_thresh: 0.65\nfree_thresh: {free}\n')


def write_map(folder, pixels, free=0.196, mode='trinary', negate=0, image='map.pgm',
              binary=True):
    """A map_server map of an (H, W) uint8 image, rows top first."""
    height, width = pixels.shape
    if binary:
        data = f'P5\n# handmade\n{width} {height}\n255\n'.encode() + pixels.astype(
            np.uint8).tobytes()
        (folder / image).write_bytes(data)
    else:
        rows = '\n'.join(' '.join(str(int(v)) for v in row) for row in pixels)
        (folder / image).write_text(f'P2\n# handmade\n{width} {height}\n255\n{rows}\n')
    path = folder / 'map.yaml'
    path.write_text(YAML.format(image=image, mode=mode, negate=negate, free=free))
    return path


# image rows top first: the top row holds the saver's three codes
SAVED = np.array([[0, 254, 205],
                  [254, 254, 0]], dtype=np.uint8)


@pytest.mark.parametrize('binary', [True, False])
def test_saver_codes_read_as_map_server_does_with_the_bottom_row_first(tmp_path, binary):
    read = read_occupancy_map(write_map(tmp_path, SAVED, binary=binary))
    grid = read.grid
    # grid row 0 is the image's bottom row
    assert grid.cells.tolist() == [[FREE, FREE, OCCUPIED], [OCCUPIED, FREE, UNKNOWN]]
    assert grid.resolution == 0.05 and grid.origin.tolist() == [-1.5, 2.0, 0.0]
    assert read.unknown_kept == 0 and read.mode == 'trinary' and not read.negate


def test_saver_unknown_stays_unknown_where_free_thresh_025_would_make_it_free(tmp_path):
    read = read_occupancy_map(write_map(tmp_path, SAVED, free=0.25))
    # map_server compares p = 50 / 255 = 0.196 < 0.25: free; here it stays unknown, counted
    assert read.grid.cells[1, 2] == UNKNOWN
    assert read.unknown_kept == 1
    # a grey the saver never writes is thresholded as map_server does
    pixels = np.array([[200, 215]], dtype=np.uint8)  # p = 0.216 free, 0.157 free at 0.25
    read = read_occupancy_map(write_map(tmp_path, pixels, free=0.25))
    assert read.grid.cells.tolist() == [[FREE, FREE]] and read.unknown_kept == 0


def test_thresholds_are_strict_comparisons(tmp_path):
    # p = (255 - v) / 255: v = 89 gives p = 0.651 > 0.65 occupied, v = 90 gives 0.647 unknown
    pixels = np.array([[89, 90, 206, 205]], dtype=np.uint8)
    cells = read_occupancy_map(write_map(tmp_path, pixels)).grid.cells[0]
    assert cells.tolist() == [OCCUPIED, UNKNOWN, FREE, UNKNOWN]


def test_negate_reads_dark_as_free(tmp_path):
    pixels = np.array([[0, 255, 128]], dtype=np.uint8)
    cells = read_occupancy_map(write_map(tmp_path, pixels, negate=1)).grid.cells[0]
    assert cells.tolist() == [FREE, OCCUPIED, UNKNOWN]


def test_pgm_of_smaller_maxval_is_scaled(tmp_path):
    (tmp_path / 'map.pgm').write_text('P2\n3 1\n15\n0 15 12\n')
    (tmp_path / 'map.yaml').write_text(YAML.format(image='map.pgm', mode='trinary', negate=0,
                                                   free=0.196))
    # 15 -> 255 free, 12 -> 204 (p = 0.2) unknown, 0 occupied
    assert read_occupancy_map(tmp_path / 'map.yaml').grid.cells[0].tolist() == [
        OCCUPIED, FREE, UNKNOWN]


def test_png_grey_colour_and_alpha(tmp_path):
    from PIL import Image
    grey = np.array([[0, 254, 205]], dtype=np.uint8)
    Image.fromarray(grey, 'L').save(tmp_path / 'grey.png')
    path = write_map(tmp_path, grey, image='grey.png')
    path.write_text(YAML.format(image='grey.png', mode='trinary', negate=0, free=0.196))
    assert read_occupancy_map(path).grid.cells[0].tolist() == [OCCUPIED, FREE, UNKNOWN]
    # colour pixels are averaged: (255 + 255 + 252) / 3 = 254 free, (0, 0, 30) occupied
    colour = np.array([[[255, 255, 252], [0, 0, 30]]], dtype=np.uint8)
    Image.fromarray(colour, 'RGB').save(tmp_path / 'colour.png')
    path.write_text(YAML.format(image='colour.png', mode='trinary', negate=0, free=0.196))
    assert read_occupancy_map(path).grid.cells[0].tolist() == [FREE, OCCUPIED]
    # trinary averages opacity in (map_server does): white fully transparent -> 191.25, p 0.25
    rgba = np.array([[[255, 255, 255, 0], [255, 255, 255, 255]]], dtype=np.uint8)
    Image.fromarray(rgba, 'RGBA').save(tmp_path / 'alpha.png')
    path.write_text(YAML.format(image='alpha.png', mode='trinary', negate=0, free=0.196))
    assert read_occupancy_map(path).grid.cells[0].tolist() == [UNKNOWN, FREE]
    # scale: a pixel that is not opaque is unknown, graded cells are unknown here
    rgba = np.array([[[255, 255, 255, 100], [255, 255, 255, 255], [128, 128, 128, 255]]],
                    dtype=np.uint8)
    Image.fromarray(rgba, 'RGBA').save(tmp_path / 'scale.png')
    path.write_text(YAML.format(image='scale.png', mode='scale', negate=0, free=0.196))
    assert read_occupancy_map(path).grid.cells[0].tolist() == [UNKNOWN, FREE, UNKNOWN]


def test_raw_mode_reads_percentages(tmp_path):
    pixels = np.array([[0, 100, 50, 255, 10]], dtype=np.uint8)
    cells = read_occupancy_map(write_map(tmp_path, pixels, mode='raw')).grid.cells[0]
    assert cells.tolist() == [FREE, OCCUPIED, UNKNOWN, UNKNOWN, FREE]


def test_round_trip_through_the_writer(tmp_path):
    rng = np.random.default_rng(3)
    cells = rng.choice(np.array([UNKNOWN, FREE, OCCUPIED], np.int8), size=(37, 51))
    grid = OccupancyGrid(cells=cells, resolution=0.05, origin=[-12.345678901, 3.25, 0.3])
    image = write_occupancy_map(tmp_path / 'out' / 'map.yaml', grid)
    assert image == tmp_path / 'out' / 'map.pgm'
    assert not list((tmp_path / 'out').glob('.*'))  # nothing staged is left
    read = read_occupancy_map(tmp_path / 'out' / 'map.yaml')
    assert np.array_equal(read.grid.cells, cells)
    assert read.grid.resolution == grid.resolution
    assert np.array_equal(read.grid.origin, grid.origin)
    # the image is what map_saver writes: P5, 0 / 254 / 205, top row = highest grid row
    shade, alpha = read_map_image(image)
    assert alpha is None and set(np.unique(shade)) <= {0.0, 205.0, 254.0}
    assert np.array_equal(shade[0] == 0, cells[-1] == OCCUPIED)


def test_image_path_relative_to_the_yaml_or_absolute(tmp_path):
    (tmp_path / 'maps').mkdir()
    path = write_map(tmp_path / 'maps', SAVED)
    absolute = tmp_path / 'elsewhere.yaml'
    absolute.write_text(path.read_text().replace('image: map.pgm',
                                                 f'image: {tmp_path / "maps" / "map.pgm"}'))
    assert np.array_equal(read_occupancy_map(absolute).grid.cells,
                          read_occupancy_map(path).grid.cells)


BAD_YAML = [
    ('image: map.pgm\n', 'resolution', None),
    (YAML.replace('image: {image}\n', ''), 'image', None),
    (YAML.replace('negate: {negate}\n', ''), 'negate', None),
    (YAML.replace('occupied_thresh: 0.65\n', ''), 'occupied_thresh', None),
    (YAML.replace('resolution: 0.05', 'resolution: 0'), 'resolution', 3),
    (YAML.replace('resolution: 0.05', 'resolution: -0.05'), 'resolution', 3),
    (YAML.replace('resolution: 0.05', 'resolution: .nan'), 'resolution', 3),
    (YAML.replace('resolution: 0.05', 'resolution: .inf'), 'resolution', 3),
    (YAML.replace('resolution: 0.05', 'resolution: true'), 'resolution', 3),
    (YAML.replace('resolution: 0.05', 'resolution: fine'), 'resolution', 3),
    (YAML.replace('[-1.5, 2.0, 0.0]', '[-1.5, 2.0]'), 'origin', 4),
    (YAML.replace('[-1.5, 2.0, 0.0]', '[-1.5, .nan, 0.0]'), 'origin', 4),
    (YAML.replace('[-1.5, 2.0, 0.0]', '[1e300, 2.0, 0.0]'), 'origin', 4),
    (YAML.replace('[-1.5, 2.0, 0.0]', '[1, 2, 1e9]'), 'origin', 4),
    (YAML.replace('[-1.5, 2.0, 0.0]', 'here'), 'origin', 4),
    (YAML.replace('negate: {negate}', 'negate: 2'), 'negate', 5),
    (YAML.replace('occupied_thresh: 0.65', 'occupied_thresh: 1.5'), 'occupied_thresh', 6),
    (YAML.replace('free_thresh: {free}', 'free_thresh: 0.9'), 'free_thresh', 7),
    (YAML.replace('mode: {mode}', 'mode: fancy'), 'mode', 2),
    (YAML.replace('image: {image}', 'image: ""'), 'image', 1),
    ('- just\n- a list\n', 'no keys', None),
    ('image: [unclosed\n', 'not YAML', 2),
]


@pytest.mark.parametrize('text, word, line', BAD_YAML)
def test_bad_yaml_names_the_file_and_line(tmp_path, text, word, line):
    write_map(tmp_path, SAVED)
    path = tmp_path / 'map.yaml'
    path.write_text(text.format(image='map.pgm', mode='trinary', negate=0, free=0.196)
                    if '{' in text else text)
    with pytest.raises(InputError) as raised:
        read_occupancy_map(path)
    assert raised.value.source == str(path)
    assert word in str(raised.value)
    assert raised.value.line == line


BAD_IMAGES = [
    (b'P5\n3 2\n255\n\x00\x01', 'truncated'),
    (b'P5\n3 2\n255\n' + bytes(7), 'after'),
    (b'P5\n3 2\n65535\n' + bytes(12), '8-bit'),
    (b'P5\n3\n', 'truncated PGM header'),
    (b'P5\n3 x\n255\n' + bytes(6), 'not integers'),
    (b'P5\n0 2\n255\n', 'not a map'),
    (b'P2\n3 2\n255\n1 2 3 4 5\n', 'truncated'),
    (b'P2\n3 2\n255\n1 2 3 4 5 6 7\n', 'extra'),
    (b'P2\n3 2\n255\n1 2 3 4 5 999\n', 'exceeds maxval'),
    (b'P2\n3 2\n255\n1 2 3 4 5 x\n', 'not an integer'),
    (b'\x89PNG\r\n\x1a\n garbage', 'cannot read'),
    (b'hello', 'cannot read'),
]


@pytest.mark.parametrize('data, word', BAD_IMAGES)
def test_bad_image_names_the_image(tmp_path, data, word):
    path = write_map(tmp_path, SAVED)
    (tmp_path / 'map.pgm').write_bytes(data)
    with pytest.raises(InputError) as raised:
        read_occupancy_map(path)
    assert raised.value.source == str(tmp_path / 'map.pgm')
    assert word in str(raised.value)


def test_missing_files(tmp_path):
    with pytest.raises(InputError, match='cannot read the map YAML'):
        read_occupancy_map(tmp_path / 'none.yaml')
    path = write_map(tmp_path, SAVED)
    (tmp_path / 'map.pgm').unlink()
    with pytest.raises(InputError, match='cannot read the map image') as raised:
        read_occupancy_map(path)
    assert raised.value.source == str(tmp_path / 'map.pgm')


def test_sixteen_bit_png_is_refused(tmp_path):
    from PIL import Image
    Image.fromarray(np.array([[0, 60000]], dtype=np.uint16)).save(tmp_path / 'deep.png')
    path = write_map(tmp_path, SAVED)
    path.write_text(YAML.format(image='deep.png', mode='trinary', negate=0, free=0.196))
    with pytest.raises(InputError, match='8-bit'):
        read_occupancy_map(path)


def quaternion(yaw):
    return [0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)]


def test_message_fields_are_row_major_from_cell_zero():
    # 3 wide, 2 high: data[0] is cell (0, 0) at the origin, x fastest
    data = [0, 100, -1,
            -1, 0, 50]
    grid = grid_from_message_fields(3, 2, 0.1, [1.0, 2.0, 0.0] + quaternion(0.5), data)
    assert grid.cells.tolist() == [[FREE, OCCUPIED, UNKNOWN], [UNKNOWN, FREE, UNKNOWN]]
    assert grid.origin[2] == pytest.approx(0.5) and grid.origin[:2].tolist() == [1.0, 2.0]
    # graded values with the thresholds: 50 is unknown at 0.65 / 0.196, 10 free, 70 occupied
    grid = grid_from_message_fields(3, 1, 0.1, [0, 0, 0] + quaternion(0), [10, 70, 50])
    assert grid.cells.tolist() == [[FREE, OCCUPIED, UNKNOWN]]


@pytest.mark.parametrize('fields, word', [
    ((0, 2, 0.1), 'no map'),
    ((3, 2, 0.0), 'resolution'),
    ((3, 2, float('nan')), 'resolution'),
    ((3, 2, 0.1, [0, 0, 0, 0, 0, 0, 0]), 'no rotation'),
    ((3, 2, 0.1, [0, 0, 0, 0.5, 0, 0, 0.866]), 'tilts'),
    ((3, 2, 0.1, [float('inf'), 0, 0, 0, 0, 0, 1]), 'origin position'),
    ((3, 2, 0.1, None, [0] * 5), '5 cell values'),
    ((3, 2, 0.1, None, [0, 0, 0, 0, 0, 101]), 'cell value 101'),
    ((3, 2, 0.1, None, [0, 0, 0, 0, 0, -2]), 'cell value -2'),
])
def test_bad_message_fields(fields, word):
    width, height, resolution = fields[:3]
    origin = fields[3] if len(fields) > 3 and fields[3] is not None else [0, 0, 0, 0, 0, 0, 1]
    data = fields[4] if len(fields) > 4 else [0] * max(width * height, 0)
    with pytest.raises(ValueError, match=word) as raised:
        grid_from_message_fields(width, height, resolution, origin, data, where='/map at 12.5')
    assert '/map at 12.5' in str(raised.value)


def test_absurd_sizes_are_refused_before_decoding(tmp_path):
    path = write_map(tmp_path, SAVED)
    (tmp_path / 'map.pgm').write_bytes(b'P5\n100000 100000\n255\n' + bytes(10))
    with pytest.raises(InputError, match='not a map'):
        read_occupancy_map(path)


@pytest.mark.parametrize('seed', range(4))
def test_corrupted_maps_read_whole_or_fail_as_bad_input(tmp_path, seed):
    """Truncated or byte-flipped YAML and images: a grid or an InputError, nothing else."""
    rng = np.random.default_rng(seed)
    cells = rng.choice(np.array([UNKNOWN, FREE, OCCUPIED], np.int8), size=(20, 30))
    grid = OccupancyGrid(cells=cells, resolution=0.05, origin=[1.0, 2.0, 0.0])
    write_occupancy_map(tmp_path / 'map.yaml', grid)
    originals = {name: (tmp_path / name).read_bytes() for name in ('map.yaml', 'map.pgm')}
    for trial in range(40):
        name = ('map.yaml', 'map.pgm')[trial % 2]
        data = bytearray(originals[name])
        if trial % 4 < 2:
            data = data[:rng.integers(0, len(data))]
        else:
            for position in rng.integers(0, len(data), 3):
                data[position] = rng.integers(0, 256)
        (tmp_path / name).write_bytes(bytes(data))
        try:
            read = read_occupancy_map(tmp_path / 'map.yaml')
        except InputError as error:
            assert str(tmp_path) in str(error)
        else:
            assert read.grid.cells.shape[0] * read.grid.cells.shape[1] > 0
        (tmp_path / name).write_bytes(originals[name])


def test_message_fields_round_trip():
    rng = np.random.default_rng(7)
    cells = rng.choice(np.array([UNKNOWN, FREE, OCCUPIED], np.int8), size=(9, 13))
    grid = OccupancyGrid(cells=cells, resolution=0.05, origin=[3.0, -4.0, -2.5])
    fields = message_fields_from_grid(grid)
    assert fields['data'][:13].tolist() == cells[0].tolist()  # cell (0, 0) first, x fastest
    back = grid_from_message_fields(**fields)
    assert np.array_equal(back.cells, cells)
    assert np.allclose(back.origin, grid.origin) and back.resolution == grid.resolution
