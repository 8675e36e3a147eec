"""The shared atomic writers: never a half-written file, JSON-safe values."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from phast_gym.fileio import atomic_write_json, atomic_write_text, jsonable


def test_jsonable_converts_numpy_and_nonfinite() -> None:
    obj = {"a": np.float32(1.5), "b": np.int64(3), "c": np.array([1.0, np.nan]), "d": (np.bool_(True), float("inf")), 4: None}
    assert jsonable(obj) == {"a": 1.5, "b": 3, "c": [1.0, None], "d": [True, None], "4": None}


def test_atomic_write_json_round_trip_and_permissions(tmp_path) -> None:
    path = atomic_write_json(tmp_path / "sub" / "x.json", {"v": np.float64(2.0), "w": float("nan")})
    assert json.loads(path.read_text()) == {"v": 2.0, "w": None}  # valid JSON: NaN is never written
    assert os.stat(path).st_mode & 0o044  # readable by others, unlike a bare mkstemp file


def test_failed_write_leaves_old_file_and_no_temp(tmp_path) -> None:
    path = tmp_path / "x.txt"
    atomic_write_text(path, "old")

    class Boom:
        def __str__(self) -> str:
            raise RuntimeError("boom")

    with pytest.raises(RuntimeError):
        atomic_write_text(path, str(Boom()))
    assert path.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["x.txt"]
