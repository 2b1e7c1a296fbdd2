"""Shared fixtures: repository paths and the public real data sets."""

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
REAL_DATA = REPO.parent / "shared" / "data" / "real"


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO


@pytest.fixture(scope="session")
def real_data_root() -> Path:
    if not REAL_DATA.is_dir():
        pytest.skip(f"public real data sets not found at {REAL_DATA} (expected beside the repo)")
    return REAL_DATA
