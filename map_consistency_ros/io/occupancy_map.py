"""nav2 map_server maps (YAML + PGM / PNG) and the `map` topic's fields -> OccupancyGrid.

The YAML keys are map_server's (nav2_map_server/src/map_io.cpp): `image` (relative to the
YAML's folder unless absolute), `resolution`, `origin` [x, y, yaw], `occupied_thresh`,
`free_thresh`, `negate` (all required, as map_server requires them) and `mode` (trinary,
scale or raw; trinary when absent). Other keys are ignored.

A pixel's shade is the mean of its colour channels, with its opacity averaged in for trinary
maps with an alpha channel (map_server does so). Its occupancy is p = (255 - shade) / 255
(p = shade / 255 when negate), thresholded as map_server does (core.localization.trinary_cells):
occupied when p > occupied_thresh, free when p < free_thresh, unknown otherwise. Scale mode
makes non-opaque pixels unknown; its graded cells between the thresholds are unknown here too
(the measure needs known free space and known obstacles). Raw mode reads the shade as an
occupancy percentage (0..100, anything else unknown), thresholded the same way.

**The saver's unknown code.** Every map_saver writes trinary maps as 0 (occupied), 254 (free)
and 205 (unknown). 205 is p = 50 / 255 = 0.196: unknown at ROS 1's free_thresh 0.196, but free
at 0.25, the default nav2's map_saver wrote into its YAML until nav2 PR 5278 (merged June 2025,
backported) fixed the saved thresholds to 0.65 / 0.196. map_server's loader did not change: it
still reads such older maps' unknown space as free. Here a trinary pixel of shade exactly 205
that the thresholds would make free stays UNKNOWN (counted in MapFile.unknown_kept): the
monitor must never judge a live scan against space nobody mapped, and a localizer that treats
it as free changes nothing about what is known there.
"""
from __future__ import annotations

import math
import numbers
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from map_consistency_ros.core.geometry import se2
from map_consistency_ros.core.localization import (FREE, OCCUPIED, UNKNOWN, OccupancyGrid,
                                                   trinary_cells)
from map_consistency_ros.io.errors import InputError
from map_consistency_ros.io.limits import DISTANCE, HEADING, implausible
from map_consistency_ros.io.staging import StagedOutputs

MODES = ('trinary', 'scale', 'raw')
# what every map_saver writes for unknown cells in trinary mode
SAVER_UNKNOWN = 205
# the pixel values and thresholds written here, those of map_saver after nav2 PR 5278
PIXEL_OF_CELL = {OCCUPIED: 0, FREE: 254, UNKNOWN: SAVER_UNKNOWN}
SAVED_OCCUPIED_THRESH = 0.65
SAVED_FREE_THRESH = 0.196
# a map of more cells than this is damage, not a floor plan (1e8 cells = 10 km square at 1 m)
MAX_CELLS = 10 ** 8


@dataclass(frozen=True)
class MapFile:
    """A map_server map as read: the grid and what the YAML said.

    `grid` the OccupancyGrid; `yaml_path`, `image_path`; `mode`, `negate`, `occupied_thresh`,
    `free_thresh` as the YAML gives them; `unknown_kept` the cells of the saver's unknown code
    (205) that map_server reads as free under these thresholds and that are unknown here.
    """

    grid: OccupancyGrid
    yaml_path: str
    image_path: str
    mode: str
    negate: bool
    occupied_thresh: float
    free_thresh: float
    unknown_kept: int


def read_occupancy_map(path: str | Path) -> MapFile:
    """Read a map_server map: its YAML and the image it names.

    Parameters
    ----------
    path: the map's YAML file.

    Returns
    -------
    The MapFile; its grid's row 0 is the image's bottom row (the lowest y). Raises InputError
    naming the YAML (and the line of the key) for a missing or unreadable file, text that is
    not a YAML mapping, a missing key, a resolution that is not a positive finite number, an
    origin that is not three finite plausible numbers, thresholds outside
    0 <= free_thresh <= occupied_thresh <= 1, a negate that is not 0 / 1 / true / false, an
    unknown mode; naming the image for a missing, unreadable, truncated or over-long image, a
    PGM that is not 8-bit, or an image of no pixels.
    """
    import yaml
    path = Path(path)
    source = str(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as error:
        raise InputError(source, f'cannot read the map YAML ({_reason(error)})') from None
    try:
        document = yaml.safe_load(text)
        lines = _key_lines(yaml.compose(text, Loader=yaml.SafeLoader))
    except yaml.YAMLError as error:
        mark = getattr(error, 'problem_mark', None)
        raise InputError(source, f'not YAML ({getattr(error, "problem", None) or error})',
                         mark.line + 1 if mark is not None else None) from None
    if not isinstance(document, dict):
        raise InputError(source, 'not a map_server map YAML (no keys at the top level)')

    def need(key: str):
        if key not in document:
            raise InputError(source, f'no `{key}` key (map_server needs it)')
        return document[key]

    def fail(key: str, message: str):
        raise InputError(source, f'`{key}`: {message}', lines.get(key))

    image = need('image')
    if not isinstance(image, str) or not image.strip():
        fail('image', f'expected an image file name, got {image!r}')
    resolution = _number(need('resolution'), 'resolution', fail)
    if not resolution > 0.0 or implausible(resolution, DISTANCE):
        fail('resolution', f'expected a positive finite number of metres, got {resolution!r}')
    origin = need('origin')
    if not isinstance(origin, list) or len(origin) != 3:
        fail('origin', f'expected [x, y, yaw], got {origin!r}')
    origin = [_number(value, 'origin', fail) for value in origin]
    for value, limit in zip(origin, (DISTANCE, DISTANCE, HEADING)):
        problem = implausible(value, limit)
        if problem:
            fail('origin', problem[1])
    occupied_thresh = _number(need('occupied_thresh'), 'occupied_thresh', fail)
    free_thresh = _number(need('free_thresh'), 'free_thresh', fail)
    for key, value in (('occupied_thresh', occupied_thresh), ('free_thresh', free_thresh)):
        if not 0.0 <= value <= 1.0:
            fail(key, f'expected a probability in [0, 1], got {value!r}')
    if free_thresh > occupied_thresh:
        fail('free_thresh', f'{free_thresh} exceeds occupied_thresh {occupied_thresh}')
    negate = need('negate')
    if isinstance(negate, bool) or negate in (0, 1):
        negate = bool(negate)
    else:
        fail('negate', f'expected 0, 1, true or false, got {negate!r}')
    mode = document.get('mode', 'trinary')
    if mode not in MODES:
        fail('mode', f'expected one of {", ".join(MODES)}, got {mode!r}')

    image_path = Path(image) if Path(image).is_absolute() else path.parent / image
    shade, alpha = read_map_image(image_path)
    cells, kept = _cells(shade, alpha, mode, negate, occupied_thresh, free_thresh)
    # image row 0 is the top of the map; the grid's row 0 the lowest y
    grid = OccupancyGrid(cells=cells[::-1], resolution=resolution, origin=np.array(origin))
    return MapFile(grid=grid, yaml_path=source, image_path=str(image_path), mode=mode,
                   negate=negate, occupied_thresh=occupied_thresh, free_thresh=free_thresh,
                   unknown_kept=kept)


def _reason(error: Exception) -> str:
    return getattr(error, 'strerror', None) or str(error)


def _key_lines(node) -> dict[str, int]:
    """1-based line of every top-level key of a composed YAML mapping."""
    import yaml
    if not isinstance(node, yaml.MappingNode):
        return {}
    return {str(key.value): key.start_mark.line + 1 for key, _ in node.value}


def _number(value, key: str, fail) -> float:
    # YAML booleans are ints in Python: `resolution: true` is no resolution
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        fail(key, f'expected a number, got {value!r}')
    value = float(value)
    if not math.isfinite(value):
        fail(key, f'{value!r} is not finite')
    return value


def _cells(shade: np.ndarray, alpha: np.ndarray | None, mode: str, negate: bool,
           occupied_thresh: float, free_thresh: float) -> tuple[np.ndarray, int]:
    """Trinary cells of an image (rows top first) and the count of saver-unknown pixels kept
    unknown; `shade` is the mean of the colour channels (0..255), `alpha` the opacity."""
    if mode == 'raw':
        percent = np.round(shade)
        occupancy = np.where((percent >= 0) & (percent <= 100), percent / 100.0, np.nan)
        return trinary_cells(occupancy, occupied_thresh, free_thresh), 0
    if mode == 'trinary' and alpha is not None:
        # map_server averages the opacity in with the three colour channels
        shade = (3.0 * shade + alpha) / 4.0
    occupancy = shade / 255.0 if negate else (255.0 - shade) / 255.0
    cells = trinary_cells(occupancy, occupied_thresh, free_thresh)
    if mode == 'scale' and alpha is not None:
        cells[alpha != 255] = UNKNOWN
    kept = 0
    if mode == 'trinary':
        saver_unknown = (shade == SAVER_UNKNOWN) & (cells == FREE)
        kept = int(np.count_nonzero(saver_unknown))
        cells[saver_unknown] = UNKNOWN
    return cells, kept


def read_map_image(path: str | Path) -> tuple[np.ndarray, np.ndarray | None]:
    """A map image's shades (and opacity), rows top first as stored.

    PGM (P2 and P5, 8-bit) is read here; other formats (PNG, BMP, ...) through Pillow
    (matplotlib's dependency). Colour pixels are averaged over R, G, B.

    Parameters
    ----------
    path: the image file.

    Returns
    -------
    (shade (H, W) float64 in 0..255, alpha (H, W) float64 in 0..255 or None without an alpha
    channel). Raises InputError naming the image for a missing, unreadable, truncated or
    over-long file, a PGM that is not 8-bit, an image format or pixel mode that cannot be
    read, or an image of no pixels.
    """
    path = Path(path)
    source = str(path)
    try:
        data = path.read_bytes()
    except OSError as error:
        raise InputError(source, f'cannot read the map image ({_reason(error)})') from None
    if data[:2] in (b'P2', b'P5'):
        return _read_pgm(data, source), None
    return _read_with_pillow(path, source)


_PGM_TOKEN = re.compile(rb'#[^\n]*|\S+')


def _read_pgm(data: bytes, source: str) -> np.ndarray:
    binary = data[:2] == b'P5'
    header, position = [], 2
    for match in _PGM_TOKEN.finditer(data, 2):
        if match.group().startswith(b'#'):
            continue
        header.append(match.group())
        position = match.end()
        if len(header) == 3:
            break
    line = data.count(b'\n', 0, position) + 1
    if len(header) < 3:
        raise InputError(source, 'truncated PGM header (need width, height and maxval)', line)
    try:
        width, height, maxval = (int(token) for token in header)
    except ValueError:
        raise InputError(source, f'PGM header fields {header!r} are not integers', line) from None
    if width <= 0 or height <= 0 or width * height > MAX_CELLS:
        raise InputError(source, f'PGM of {width} x {height} pixels: not a map', line)
    if not 0 < maxval <= 255:
        raise InputError(source, f'PGM maxval {maxval}: only 8-bit maps (maxval 1..255) are '
                                 'read', line)
    count = width * height
    if binary:
        # exactly one whitespace byte ends the header
        raster = data[position + 1:]
        if len(raster) < count:
            raise InputError(source, f'truncated PGM: {len(raster)} of {count} pixel bytes')
        if len(raster) > count:
            raise InputError(source, f'{len(raster) - count} bytes after the {width} x '
                                     f'{height} pixels: not one PGM image')
        values = np.frombuffer(raster, dtype=np.uint8).astype(np.float64)
    else:
        tokens = data[position:].split()
        if len(tokens) != count:
            problem = 'truncated' if len(tokens) < count else 'extra values'
            raise InputError(source, f'{len(tokens)} pixel values for {width} x {height} '
                                     f'pixels ({problem})')
        try:
            values = np.array([int(token) for token in tokens], dtype=np.float64)
        except ValueError:
            raise InputError(source, 'a PGM pixel value is not an integer') from None
    if values.size and values.max() > maxval:
        raise InputError(source, f'a pixel value {int(values.max())} exceeds maxval {maxval}')
    if maxval != 255:
        values = values * (255.0 / maxval)
    return values.reshape(height, width)


def _read_with_pillow(path: Path, source: str) -> tuple[np.ndarray, np.ndarray | None]:
    try:
        from PIL import Image, UnidentifiedImageError
    except ImportError:  # pragma: no cover - Pillow comes with matplotlib
        raise InputError(source, 'not a PGM, and Pillow is not installed to read other '
                                 'image formats') from None
    try:
        with Image.open(path) as image:
            # the header's size, before decoding a damaged or absurd image
            if image.width * image.height > MAX_CELLS:
                raise InputError(source, f'image of {image.width} x {image.height} pixels: '
                                         'not a map')
            image.load()
            mode = image.mode
            if mode == 'P':
                image = image.convert('RGBA' if 'transparency' in image.info else 'RGB')
            elif mode == '1':
                image = image.convert('L')
            mode = image.mode
            if mode not in ('L', 'LA', 'RGB', 'RGBA'):
                raise InputError(source, f'pixel mode {mode}: only 8-bit grey or colour maps '
                                         'are read')
            pixels = np.asarray(image, dtype=np.float64)
    except InputError:
        raise
    except (OSError, UnidentifiedImageError, ValueError, SyntaxError) as error:
        raise InputError(source, f'cannot read the map image ({error})') from None
    if pixels.size == 0:
        raise InputError(source, 'an image of no pixels')
    if pixels.ndim == 2:
        return pixels, None
    colour = 1 if mode in ('L', 'LA') else 3
    alpha = pixels[..., colour] if mode in ('LA', 'RGBA') else None
    return pixels[..., :colour].mean(axis=-1), alpha


def grid_from_message_fields(width: int, height: int, resolution: float,
                             origin_xyz_quat, data, occupied_thresh: float = SAVED_OCCUPIED_THRESH,
                             free_thresh: float = SAVED_FREE_THRESH,
                             where: str = 'OccupancyGrid') -> OccupancyGrid:
    """The grid of a nav_msgs/OccupancyGrid message's fields (ROS-free).

    Values -1 are unknown; 0..100 are occupancy percentages, thresholded as a map_server map
    (p = value / 100; map_server's own trinary maps carry only 0, 100 and -1, which any
    thresholds in (0, 1) keep).

    Parameters
    ----------
    width, height: info.width and info.height, positive.
    resolution: info.resolution, metres per cell.
    origin_xyz_quat: info.origin as 7 numbers (x, y, z, qx, qy, qz, qw); the rotation must be
        about z (a tilted origin is no 2-D map).
    data: the W * H cell values, row-major from cell (0, 0), x fastest.
    occupied_thresh, free_thresh: the thresholds of graded values (those of a map saved by
        map_saver by default).
    where: how messages name the message in errors (topic and stamp).

    Returns
    -------
    The OccupancyGrid. Raises ValueError naming `where` for a non-positive size, a resolution
    or origin that is not finite and plausible, a tilted origin, data of another length or a
    value outside -1..100.
    """
    try:
        width, height = int(width), int(height)
    except (TypeError, ValueError):
        raise ValueError(f'{where}: width and height must be integers, got {width!r}, '
                         f'{height!r}') from None
    if width <= 0 or height <= 0 or width * height > MAX_CELLS:
        raise ValueError(f'{where}: a {width} x {height} grid is no map')
    resolution = float(resolution)
    if not (math.isfinite(resolution) and 0.0 < resolution <= DISTANCE.bound):
        raise ValueError(f'{where}: resolution {resolution!r} is not a positive finite number')
    origin = np.asarray(origin_xyz_quat, dtype=np.float64).reshape(-1)
    if origin.shape != (7,):
        raise ValueError(f'{where}: origin must be 7 numbers (x, y, z, qx, qy, qz, qw)')
    problem = implausible(origin[:3], DISTANCE)
    if problem:
        raise ValueError(f'{where}: origin position {problem[1]}')
    quaternion = origin[3:]
    norm = float(np.linalg.norm(quaternion)) if np.all(np.isfinite(quaternion)) else 0.0
    if norm == 0.0:
        raise ValueError(f'{where}: origin orientation {quaternion.tolist()} is no rotation')
    if math.hypot(quaternion[0], quaternion[1]) > 1e-3 * norm:
        raise ValueError(f'{where}: origin orientation {quaternion.tolist()} tilts the map '
                         '(not a rotation about z)')
    yaw = se2.yaw_from_quaternion(*quaternion)
    values = np.asarray(data).reshape(-1)
    if values.size != width * height:
        raise ValueError(f'{where}: {values.size} cell values for {width} x {height} cells')
    values = values.astype(np.int64)
    if values.size and (values.min() < -1 or values.max() > 100):
        bad = values[(values < -1) | (values > 100)][0]
        raise ValueError(f'{where}: cell value {bad} is not -1 (unknown) or 0..100')
    occupancy = np.where(values >= 0, values / 100.0, np.nan)
    try:
        cells = trinary_cells(occupancy, occupied_thresh, free_thresh)
    except ValueError as error:
        raise ValueError(f'{where}: {error}') from None
    return OccupancyGrid(cells=cells.reshape(height, width), resolution=resolution,
                         origin=np.array([origin[0], origin[1], yaw]))


def write_occupancy_map(yaml_path: str | Path, grid: OccupancyGrid,
                        image_name: str | None = None) -> Path:
    """Write a grid as a map_server trinary map: a YAML and a binary PGM beside it, both whole
    or neither (io/staging.py).

    Pixels are map_saver's: 0 occupied, 254 free, 205 unknown; the YAML states mode trinary,
    negate 0 and the thresholds 0.65 / 0.196 that read them back exactly.

    Parameters
    ----------
    yaml_path: the YAML to write (an existing one is replaced; its folder made if missing).
    grid: the map.
    image_name: the PGM's file name, in the YAML's folder; the YAML's stem + '.pgm' when None.

    Returns
    -------
    The image's path.
    """
    yaml_path = Path(yaml_path)
    image_name = image_name or yaml_path.stem + '.pgm'
    image_path = yaml_path.parent / image_name
    pixels = np.full(grid.cells.shape, PIXEL_OF_CELL[UNKNOWN], dtype=np.uint8)
    pixels[grid.cells == FREE] = PIXEL_OF_CELL[FREE]
    pixels[grid.cells == OCCUPIED] = PIXEL_OF_CELL[OCCUPIED]
    x, y, yaw = (float(value) for value in grid.origin)
    # repr round-trips every float exactly
    text = (f'image: {image_name}\nmode: trinary\nresolution: {grid.resolution!r}\n'
            f'origin: [{x!r}, {y!r}, {yaw!r}]\nnegate: 0\n'
            f'occupied_thresh: {SAVED_OCCUPIED_THRESH}\nfree_thresh: {SAVED_FREE_THRESH}\n')
    with StagedOutputs() as outputs:
        header = f'P5\n# map_consistency_ros\n{grid.width} {grid.height}\n255\n'.encode()
        # image row 0 is the top of the map
        outputs.path(image_path).write_bytes(header + pixels[::-1].tobytes())
        outputs.path(yaml_path).write_text(text)
    return image_path


def message_fields_from_grid(grid: OccupancyGrid) -> dict:
    """The fields of a nav_msgs/OccupancyGrid message carrying a grid (ROS-free), the inverse
    of grid_from_message_fields.

    Parameters
    ----------
    grid: the map.

    Returns
    -------
    {'width', 'height', 'resolution', 'origin_xyz_quat' (7 floats: x, y, 0, 0, 0, qz, qw),
    'data' (W * H int8, row-major from cell (0, 0), x fastest: -1, 0, 100)}.
    """
    z, w = se2.quaternion_from_yaw(float(grid.origin[2]))
    return {'width': grid.width, 'height': grid.height, 'resolution': grid.resolution,
            'origin_xyz_quat': [float(grid.origin[0]), float(grid.origin[1]), 0.0, 0.0, 0.0,
                                float(z), float(w)],
            'data': grid.cells.reshape(-1).copy()}
