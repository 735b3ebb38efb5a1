import os
from pathlib import Path

import pytest

# FMUs built by the tests ship the generic C kernel only, unless a test asks for the one
# built for its scene (test_ckernel_scene.py): that one gives the generic kernel's doubles
# (tested there, in the harness and in FMUs) and costs seconds of compiling per scene.
os.environ.setdefault("MBDFMU_SCENE_KERNEL", "0")

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"


@pytest.fixture
def scenes_dir() -> Path:
    return SCENES


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: a long run, skipped unless MBDFMU_SLOW=1")
