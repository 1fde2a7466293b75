"""Shared fixtures: the real datasets in ../shared/data beside the repository."""
from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / 'shared' / 'data'


@pytest.fixture(scope='session')
def shared_data() -> Path:
    """Folder of the real datasets; CI clones the repo with ../shared beside it."""
    if not SHARED_DATA.is_dir():
        raise FileNotFoundError(f'real datasets not found at {SHARED_DATA}')
    return SHARED_DATA
