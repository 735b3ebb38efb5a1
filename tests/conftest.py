from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"


@pytest.fixture
def scenes_dir() -> Path:
    return SCENES


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: a long run, skipped unless MBDFMU_SLOW=1")
