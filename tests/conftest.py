"""Shared fixtures: the dataset cache always lives in a temporary directory during tests."""

from __future__ import annotations

import pytest


@pytest.fixture(autouse=True)
def _isolated_dataset_cache(tmp_path_factory, monkeypatch):
    """Never touch the user's ~/.cache/phast from the test suite."""
    monkeypatch.setenv("PHAST_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "phast_cache"))
