"""Shared fixtures: the real-data folder, Hypothesis profiles, small synthetic DEMs."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, settings

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("CRATERSCAPE_SHARED_DATA", REPO.parent / "shared" / "data"))

# CI draws the same examples on every run (derandomize), so a red CI is reproducible and a
# green one is not luck; "thorough" explores afresh and keeps failures in .hypothesis/.
settings.register_profile(
    "ci", max_examples=25, deadline=None, derandomize=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
settings.register_profile("thorough", max_examples=300, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


def _shared_file(*parts) -> Path:
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"real data {path} is absent (../shared/data is not part of the repository)")
    return path


@pytest.fixture
def shared_file():
    """``shared_file("lunar", "LDEM_4.LBL")``: path under ../shared/data, or skip with a reason."""
    return _shared_file


@pytest.fixture
def rng():
    """A NumPy generator for building test inputs (never used by the library)."""
    return np.random.default_rng(12345)
