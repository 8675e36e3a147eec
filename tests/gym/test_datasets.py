"""Batched dataset generation: shapes, determinism, agreement with the env, cache integrity."""

from __future__ import annotations

import os
import pathlib
import warnings

import gymnasium as gym
import numpy as np
import pytest

import phast_gym
from phast_gym import datasets
from phast_gym.datasets import cache_dir, make_dataset, make_splits
from tests import ROOT


def test_shapes_and_contents() -> None:
    ds = make_dataset("PHAST/WindyCartPole-v0", 8, T=30, seed=1, cache=False)
    assert ds.q.shape == ds.q_true.shape == ds.p.shape == ds.damping.shape == (8, 30, 2)
    assert ds.u.shape == (8, 29, 2) and ds.dt == 0.02 and ds.angle_dims == (1,)
    assert np.all(ds.q[..., 1] >= -np.pi) and np.all(ds.q[..., 1] < np.pi)
    assert np.allclose(ds.q[..., 0], ds.q_true[..., 0])
    s = phast_gym.make_env_system("PHAST/WindyCartPole-v0")
    assert np.allclose(ds.damping[..., 1], 0.3 + 0.5 * np.abs(np.sin(ds.q_true[..., 1])))
    assert np.allclose(ds.damping[..., 0], s.d_cart)


def test_deterministic_in_seed() -> None:
    a = make_dataset("PHAST/WindyPendulum-v0", 5, T=20, seed=3, cache=False, obs_noise_std=0.01)
    b = make_dataset("PHAST/WindyPendulum-v0", 5, T=20, seed=3, cache=False, obs_noise_std=0.01)
    c = make_dataset("PHAST/WindyPendulum-v0", 5, T=20, seed=4, cache=False, obs_noise_std=0.01)
    assert np.array_equal(a.q, b.q) and np.array_equal(a.p, b.p)
    assert not np.array_equal(a.q, c.q)
    assert 0.005 < np.std(a.q - np.angle(np.exp(1j * a.q_true))) < 0.02


@pytest.mark.parametrize("env_id", ["PHAST/WindyPendulum-v0", "PHAST/WindyCartPole-v0", "PHAST/LennardJones3-v0",
                                    "PHAST/PredatorPrey-v0", "PHAST/NBody3-v0"])
def test_batched_simulator_equals_single_env(env_id: str) -> None:
    rng = np.random.default_rng(0)
    n = phast_gym.make_env_system(env_id).n
    u = rng.uniform(-1, 1, (4, 25, n))
    ds = make_dataset(env_id, 4, T=26, seed=5, u=u, cache=False)
    env = gym.make(env_id, dtype=np.float64).unwrapped
    for i in range(4):
        env.reset(options={"state": np.concatenate([ds.q_true[i, 0], ds.p[i, 0]])})
        for t in range(25):
            obs, _, _, _, info = env.step(u[i, t])
            assert np.allclose(info["state"], np.concatenate([ds.q_true[i, t + 1], ds.p[i, t + 1]]), rtol=0, atol=1e-12)
            assert np.allclose(obs, ds.q[i, t + 1], atol=1e-12)


def test_large_batch_agrees_with_single_env_to_integration_accuracy() -> None:
    """Large batches run the same NumPy path as small ones (no batch-size threshold switches sin/cos
    kernels): a chaotic 2-dof env over 300 samples still agrees with the single env to 1e-12."""
    env_id = "PHAST/WindyDoublePendulum-v0"
    ds = make_dataset(env_id, 300, T=40, seed=5, cache=False)
    env = gym.make(env_id, dtype=np.float64).unwrapped
    for i in (0, 150, 299):
        env.reset(options={"state": np.concatenate([ds.q_true[i, 0], ds.p[i, 0]])})
        for t in range(39):
            _, _, _, _, info = env.step(np.zeros(2))
            assert np.allclose(info["state"], np.concatenate([ds.q_true[i, t + 1], ds.p[i, t + 1]]), rtol=0, atol=1e-12)


def test_actuated_dofs_and_u_validation() -> None:
    ds = make_dataset("PHAST/WindyCartPole-v0", 3, T=10, u=np.ones((3, 9, 1)), actuated_dofs=[1], cache=False)
    assert ds.u.shape == (3, 9, 1) and ds.actuated_dofs == (1,)
    with pytest.raises(ValueError, match="u must broadcast"):
        make_dataset("PHAST/WindyCartPole-v0", 3, T=10, u=np.ones((3, 5, 2)), cache=False)
    with pytest.raises(ValueError, match="finite"):
        make_dataset("PHAST/Pendulum-v0", 2, T=5, u=np.full((2, 4, 1), np.nan), cache=False)
    with pytest.raises(ValueError, match="distinct indices"):
        make_dataset("PHAST/WindyCartPole-v0", 3, T=10, actuated_dofs=[1, 1], cache=False)
    with pytest.raises(ValueError, match="n_traj"):
        make_dataset("PHAST/Pendulum-v0", 0, T=5, cache=False)
    with pytest.raises(ValueError, match="integer indices"):
        make_dataset("PHAST/WindyCartPole-v0", 3, T=10, actuated_dofs=[0.5], cache=False)
    with pytest.raises(ValueError, match="env kwarg"):
        make_dataset("PHAST/Pendulum-v0", 2, T=5, render_mode="rgb_array", cache=False)
    with pytest.raises(gym.error.Error):
        make_dataset("PHAST/NoSuchEnv-v0", 2, T=5)


def test_paper_split_sizes() -> None:
    splits = make_splits("PHAST/Pendulum-v0", T=20)
    assert [len(splits[k]) for k in ("train", "val", "test")] == [1000, 200, 200]
    assert splits["train"].config["seed"] == 42
    full = make_dataset("PHAST/Pendulum-v0", 1400, T=20)
    assert np.array_equal(splits["test"].q, full.q[1200:])


def test_cache_hit_skips_simulation(monkeypatch) -> None:
    pattern = "PHAST_DampedPendulum-v0-*.npz"  # the cache is shared by the session: count what this test adds
    before = set(cache_dir().glob(pattern)) if cache_dir().exists() else set()
    a = make_dataset("PHAST/DampedPendulum-v0", 6, T=15, seed=9)
    assert len(set(cache_dir().glob(pattern)) - before) == 1

    def boom(*args, **kwargs):
        raise AssertionError("simulate called on a cache hit")

    original = datasets.simulate
    monkeypatch.setattr(datasets, "simulate", boom)
    b = make_dataset("PHAST/DampedPendulum-v0", 6, T=15, seed=9)
    assert np.array_equal(a.q, b.q) and b.config == a.config
    # any change of configuration is a different key
    monkeypatch.setattr(datasets, "simulate", original)
    make_dataset("PHAST/DampedPendulum-v0", 6, T=15, seed=9, gamma=0.6)
    assert len(set(cache_dir().glob(pattern)) - before) == 2


@pytest.mark.parametrize("damage", ["truncate", "garble", "flip"])
def test_corrupted_cache_is_detected_and_regenerated(damage: str) -> None:
    a = make_dataset("PHAST/RLCCircuit-v0", 4, T=12, seed=11)
    (path,) = list(cache_dir().glob("PHAST_RLCCircuit-v0-*.npz"))
    raw = bytearray(path.read_bytes())
    if damage == "truncate":
        raw = raw[: len(raw) // 2]
    elif damage == "garble":
        raw[:64] = b"\0" * 64
    else:  # a single flipped byte inside the array payload: caught by the checksum
        z = np.load(path)
        q = z["q"].copy()
        q[0, 3, 0] += 1e-3
        np.savez(path, **{k: z[k] for k in z.files if k != "q"}, q=q)
        raw = bytearray(path.read_bytes())
    path.write_bytes(bytes(raw))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        b = make_dataset("PHAST/RLCCircuit-v0", 4, T=12, seed=11)
    assert any("regenerating" in str(x.message) for x in w)
    assert np.array_equal(a.q, b.q)
    # the regenerated file is healthy again
    c = make_dataset("PHAST/RLCCircuit-v0", 4, T=12, seed=11)
    assert np.array_equal(a.q, c.q)


def _cache_file(env_id: str, **kw) -> tuple[datasets.Dataset, pathlib.Path]:
    """A dataset written to the cache, and its cache file."""
    before = set(cache_dir().glob("*.npz")) if cache_dir().exists() else set()
    ds = make_dataset(env_id, **kw)
    (path,) = set(cache_dir().glob("*.npz")) - before
    return ds, path


#: a file object that writes half of what it is given to disk, then calls ``then()``: a write cut short midway
#: (source text, so that a child process can define it too)
HALF_WRITER = """
import os


class HalfWriter:
    def __init__(self, fh, then):
        self.fh, self.then = fh, then

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.fh.close()

    def write(self, data):
        self.fh.write(data[: len(data) // 2])
        self.fh.flush()
        os.fsync(self.fh.fileno())
        self.then()
"""


def test_cache_write_killed_midway_leaves_the_old_file() -> None:
    """A rewrite of a cache file whose process is SIGKILLed after half its bytes reached the disk: the previous file
    is intact and loads, the half-written temp file is not a loadable dataset and is never read as the cache, and
    the next write of that file removes it."""
    import signal
    import subprocess
    import sys

    kw = {"n_traj": 3, "T": 10, "seed": 2}
    old, path = _cache_file("PHAST/HeatExchange-v0", **kw)
    old_bytes = path.read_bytes()
    code = HALF_WRITER + f"""
import signal
from phast_gym import datasets

ds = datasets._load({str(path)!r}, {old.config!r})
ds.q = ds.q + 1.0  # different content, same cache file
real_fdopen = os.fdopen
os.fdopen = lambda fd, mode: HalfWriter(real_fdopen(fd, mode), lambda: os.kill(os.getpid(), signal.SIGKILL))
datasets._save(datasets.Path({str(path)!r}), ds)
"""
    root = str(ROOT)
    env = {**os.environ, "PYTHONPATH": root + os.pathsep + os.environ.get("PYTHONPATH", "")}
    res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert res.returncode == -signal.SIGKILL, res.stderr
    assert path.read_bytes() == old_bytes
    temps = [p for p in path.parent.iterdir() if p.name.startswith(f".{path.name}.") and p.name.endswith(".tmp")]
    assert len(temps) == 1 and 0 < temps[0].stat().st_size < len(old_bytes)  # the killed writer's half file
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # loaded from the cache, not regenerated after a failed load
        again = make_dataset("PHAST/HeatExchange-v0", **kw)
    np.testing.assert_array_equal(again.q, old.q)
    with pytest.raises(ValueError, match="unreadable cache file"):
        datasets._load(temps[0], old.config)
    datasets._save(path, old)  # the next write of the file clears the dead writer's temp
    assert not temps[0].exists() and path.read_bytes() == old_bytes


def test_cache_write_failing_midway_leaves_the_old_file(monkeypatch) -> None:
    """A write that fails after half the bytes reached the disk (disk full) leaves the previous file intact and
    loadable and no temp file behind."""
    kw = {"n_traj": 3, "T": 10, "seed": 3}
    old, path = _cache_file("PHAST/HeatExchange-v0", **kw)
    old_bytes = path.read_bytes()
    ns: dict = {}
    exec(HALF_WRITER, ns)

    def disk_full() -> None:
        raise OSError(28, "No space left on device")

    real_fdopen = os.fdopen
    monkeypatch.setattr(os, "fdopen", lambda fd, mode: ns["HalfWriter"](real_fdopen(fd, mode), disk_full))
    changed = old.subset(slice(None))
    changed.q = changed.q + 1.0
    with pytest.raises(OSError, match="No space left"):
        datasets._save(path, changed)
    monkeypatch.undo()
    assert path.read_bytes() == old_bytes
    assert [p.name for p in path.parent.iterdir() if p.name.startswith(f".{path.name}.")] == []
    np.testing.assert_array_equal(datasets._load(path, old.config).q, old.q)


@pytest.mark.parametrize("noise", [-1.0, float("nan"), float("inf"), "0.1", True])
def test_bad_obs_noise_std_is_rejected_and_nothing_cached(noise) -> None:
    before = set(os.listdir(cache_dir())) if cache_dir().exists() else set()
    with pytest.raises(ValueError, match="obs_noise_std"):
        make_dataset("PHAST/Pendulum-v0", 2, T=5, seed=123, obs_noise_std=noise)
    after = set(os.listdir(cache_dir())) if cache_dir().exists() else set()
    assert after == before


def test_stale_temp_of_a_killed_write_is_removed(tmp_path) -> None:
    """A killed writer's temp file (its pid gone, or a legacy tmp*.tmp older than a day) goes with the next write."""
    import subprocess
    import sys

    from phast_gym.fileio import _HOST, atomic_write_bytes

    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()  # a pid that no longer runs
    dead = tmp_path / f".x.bin.{_HOST}-{proc.pid}.abc123.tmp"
    dead.write_bytes(b"")
    legacy = tmp_path / "tmpab12cd.tmp"
    legacy.write_bytes(b"")
    os.utime(legacy, (0, 0))
    live = tmp_path / f".x.bin.{_HOST}-{os.getppid()}.zz.tmp"  # a live writer's temp is kept
    live.write_bytes(b"")
    atomic_write_bytes(tmp_path / "x.bin", b"data")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["x.bin", live.name])


def test_port_excitation_is_held_seeded_and_checked():
    from phast_gym.datasets import PortExcitation

    e = PortExcitation(2.0, hold=4, seed=1)
    u = e.for_env("PHAST/WindyCartPole-v0", 8, 11)
    assert u.shape == (8, 10, 2)
    np.testing.assert_array_equal(u[:, 0], u[:, 3])  # held for 4 steps
    assert not np.array_equal(u[:, 3], u[:, 4])
    np.testing.assert_array_equal(u, PortExcitation(2.0, hold=4, seed=1).for_env("PHAST/WindyCartPole-v0", 8, 11))
    assert not np.array_equal(u, PortExcitation(2.0, hold=4, seed=2).for_env("PHAST/WindyCartPole-v0", 8, 11))
    assert e.for_env("PHAST/WindyCartPole-v0", 8, 11, actuated_dofs=[1]).shape == (8, 10, 1)
    big = PortExcitation(1.5, hold=1).signal(400, 101, 1)
    assert big.std() == pytest.approx(1.5, rel=0.02)
    for bad in ({"std": -1.0}, {"std": float("nan")}, {"std": 1.0, "hold": 0}, {"std": 1.0, "seed": -1}):
        with pytest.raises(ValueError, match="port excitation"):
            PortExcitation(**bad)
    ds = make_dataset("PHAST/DampedPendulum-v0", 8, T=11, seed=0, u=e.for_env("PHAST/DampedPendulum-v0", 8, 11),
                      cache=False)
    free = make_dataset("PHAST/DampedPendulum-v0", 8, T=11, seed=0, cache=False)
    assert not np.allclose(ds.q, free.q)  # the input drives the data


def test_dataset_carries_the_system_of_its_kwargs(tmp_path, monkeypatch) -> None:
    """The System that generated a dataset (non-default kwargs) is built once and shared by its splits, whether the
    dataset is generated or read from the cache; metrics and plots read it (phast_model.train.metrics.data_system)."""
    import dataclasses

    from phast_model.train.metrics import data_system, energy_diagnostics

    monkeypatch.setenv("PHAST_CACHE_DIR", str(tmp_path))
    for _ in range(2):  # generated, then from the cache
        splits = make_splits("PHAST/Pendulum-v0", 2, 1, 1, T=20, seed=3, mass=2.0)
        system = splits["train"].system
        assert system is not None and system.key_params()["mass"] == 2.0
        assert all(s.system is system for s in splits.values()) and data_system(splits["test"]) is system
    test = splits["test"]
    rebuilt = data_system(dataclasses.replace(test, system=None))  # a dataset without one: from its config
    assert rebuilt is not system and rebuilt.key_params() == system.key_params()
    q = test.q[:, :8]
    assert energy_diagnostics(system, q, test.dt, test.angle_dims) == energy_diagnostics(rebuilt, q, test.dt,
                                                                                         test.angle_dims)
