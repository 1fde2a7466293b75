"""`warm-up` runs every compiled path once and leaves the kernels in numba's cache."""
from pathlib import Path

import numba

from map_consistency_ros.cli.main import main
from map_consistency_ros.core.consistency import _check
from map_consistency_ros.core.geometry import _measure, _spatial_index, _viewpoints
from map_consistency_ros.core.verdict import _registration


def _cached(module) -> bool:
    # numba keeps a module's kernels in its __pycache__, or under NUMBA_CACHE_DIR
    stem = module.__name__.rsplit('.', 1)[1]
    places = [Path(module.__file__).parent / '__pycache__']
    if numba.config.CACHE_DIR:
        places.append(Path(numba.config.CACHE_DIR))
    return any(next(place.rglob(f'{stem}.*.nbi'), None) for place in places if place.exists())


def test_warm_up_leaves_every_paths_kernels_in_the_cache(capsys):
    assert main(['warm-up']) == 0
    assert capsys.readouterr().out.startswith('warm-up: compiled kernels cached (')
    for module in (_measure, _registration, _viewpoints, _check, _spatial_index):
        assert _cached(module), module.__name__
