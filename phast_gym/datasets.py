"""Batched dataset generation with the paper's split and an on-disk cache.

All trajectories of a dataset are integrated at once by
:func:`phast_gym.integrate.simulate` (the same physics and integrator as the
env, vectorized over trajectories).  Files are cached under
``$PHAST_CACHE_DIR`` (default ``~/.cache/phast``) keyed by a hash of the full
configuration; writes are atomic and every array carries a checksum, so a
truncated or corrupted cache file is detected and regenerated.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import os
import warnings
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from .env import parse_actuated_dofs
from .fileio import atomic_write_bytes
from .integrate import simulate
from .registry import ENV_KWARGS, make_env_system, resolve_env_id
from .systems import NUMPY, System, wrap

#: 2: Hermite-located kink crossings, vectorized sin/cos in the batched simulator.
#: 3: sin/cos back on NumPy (torch's kernels differed from libm's by 1 ulp in ~0.1 % of evaluations, up to
#: ~1e-14 after 200 steps, more in chaotic systems) and predator-prey at 4 RK4 substeps instead of 2 (its
#: predator density missed the 1e-5 accuracy contract by up to 4e-5): version-2 files hold other values.
CACHE_VERSION = 3
_ARRAYS = ("q", "q_true", "p", "u", "damping")


@dataclass
class Dataset:
    """A batch of trajectories of one env (float64 arrays).

    Attributes
    ----------
    q : (N, T, n) observation: true q plus observation noise, angles wrapped.
    q_true : (N, T, n) true q, angles unwrapped.
    p : (N, T, n) true momentum (predator density for predator-prey).
    u : (N, T-1, m) port input applied over each interval [t, t+1].
    damping : (N, T, n) diagonal of the true D(q_t).
    dt : sampling interval.
    system : the :class:`~phast_gym.systems.System` that generated the data (its kwargs), built once by
        :func:`make_dataset` and shared by every subset, so metrics, plots and energy diagnostics use the data's
        own physics without rebuilding it (None for a dataset assembled by hand).
    """

    env_id: str
    q: np.ndarray
    q_true: np.ndarray
    p: np.ndarray
    u: np.ndarray
    damping: np.ndarray
    dt: float
    angle_dims: tuple[int, ...]
    actuated_dofs: tuple[int, ...]
    config: dict[str, Any] = field(default_factory=dict)
    system: System | None = field(default=None, repr=False, compare=False)

    @property
    def n_traj(self) -> int:
        return self.q.shape[0]

    @property
    def T(self) -> int:
        return self.q.shape[1]

    def __len__(self) -> int:
        return self.n_traj

    def subset(self, idx: slice | np.ndarray | Sequence[int]) -> Dataset:
        """Trajectories ``idx`` (slice or index array) as a new dataset."""
        kw = {k: getattr(self, k)[idx] for k in _ARRAYS}
        return Dataset(self.env_id, dt=self.dt, angle_dims=self.angle_dims, actuated_dofs=self.actuated_dofs,
                       config=dict(self.config), system=self.system, **kw)


def _config_key(config: Mapping[str, object]) -> str:
    blob = json.dumps(config, sort_keys=True, default=str).encode()
    return hashlib.sha256(blob).hexdigest()[:24]


def cache_dir() -> Path:
    """Directory of the dataset cache (``$PHAST_CACHE_DIR`` or ``~/.cache/phast``)."""
    return Path(os.environ.get("PHAST_CACHE_DIR", Path.home() / ".cache" / "phast")) / "datasets"


def _checksum(arr: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(arr).tobytes()).hexdigest()


def _save(path: Path, ds: Dataset) -> None:
    meta = {"env_id": ds.env_id, "dt": ds.dt, "angle_dims": list(ds.angle_dims),
            "actuated_dofs": list(ds.actuated_dofs), "config": ds.config,
            "checksums": {k: _checksum(getattr(ds, k)) for k in _ARRAYS}}
    buf = io.BytesIO()
    np.savez(buf, meta=np.array(json.dumps(meta)), **{k: getattr(ds, k) for k in _ARRAYS})
    atomic_write_bytes(path, buf.getvalue())


def _load(path: Path, config: Mapping[str, object]) -> Dataset:
    """Load a cache file, raising ``ValueError`` on any inconsistency."""
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            arrays = {k: z[k] for k in _ARRAYS}
    except (OSError, KeyError, ValueError, zipfile.BadZipFile, EOFError, json.JSONDecodeError) as exc:
        raise ValueError(f"unreadable cache file {path}: {exc}") from None
    if meta.get("config") != json.loads(json.dumps(config, default=str)):
        raise ValueError(f"cache file {path} holds another configuration")
    for k in _ARRAYS:
        if _checksum(arrays[k]) != meta["checksums"][k]:
            raise ValueError(f"checksum mismatch for '{k}' in {path}")
    return Dataset(meta["env_id"], dt=float(meta["dt"]), angle_dims=tuple(meta["angle_dims"]),
                   actuated_dofs=tuple(meta["actuated_dofs"]), config=meta["config"], **arrays)


def check_noise_std(value: object) -> float:
    """``obs_noise_std`` as the env takes it: a real number >= 0 and finite, else ValueError (nothing generated or
    cached)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"obs_noise_std must be a real number >= 0, got {value!r}")
    noise = float(value)
    if not (noise >= 0 and math.isfinite(noise)):
        raise ValueError(f"obs_noise_std must be >= 0 and finite, got {value!r}")
    return noise


def make_dataset(
    env_id: str,
    n_traj: int,
    T: int = 200,
    seed: int = 42,
    u: np.ndarray | None = None,
    cache: bool = True,
    backend: str = "numpy",
    **env_kwargs: Any,
) -> Dataset:
    """Generate ``n_traj`` trajectories of ``T`` samples of a registered env, all at once.

    Parameters
    ----------
    env_id : a ``PHAST/*`` id.
    n_traj, T : number of trajectories and samples per trajectory (T - 1 steps).
    seed : dataset seed (initial states, observation noise, Langevin noise).
    u : optional port input, broadcastable to (n_traj, T-1, m); default zeros.
    cache : read/write the on-disk cache.
    backend : ``"numpy"`` (default; :func:`phast_gym.integrate.simulate`) or ``"compiled"``
        (:func:`phast_gym.compiled.simulate_compiled`: the same RK4 and physics fused by
        ``torch.compile``: faster once compiled, but seconds to a minute of compilation the first time per
        system and batch size; worth it for large or many datasets; speed-ups measured in docs/envs.md).  The two
        agree to ~1e-12 and are cached separately.
    env_kwargs : the env's kwargs (physical parameters, ``obs_noise_std``,
        ``actuated_dofs``); other env-only kwargs are rejected.
    """
    env_id = resolve_env_id(env_id)
    _check_request(n_traj, T, backend, env_kwargs)
    noise = check_noise_std(env_kwargs.get("obs_noise_std", 0.0))
    system = make_env_system(env_id, **env_kwargs)
    actuated = parse_actuated_dofs(env_kwargs.get("actuated_dofs"), system.n)
    u_arr = _port_input(u, n_traj, T, len(actuated))
    config = {
        "version": CACHE_VERSION, "env_id": env_id, "n_traj": int(n_traj), "T": int(T), "seed": int(seed),
        "system": system.name, "params": system.key_params(), "obs_noise_std": noise, "actuated_dofs": list(actuated),
        "substeps": env_kwargs.get("substeps", system.substeps),
        "u": None if u is None else _checksum(u_arr),
    }
    if backend != "numpy":  # keeps the keys of existing NumPy-generated caches
        config["backend"] = backend
    path = cache_dir() / f"{env_id.replace('/', '_')}-{_config_key(config)}.npz"
    if cache and path.exists():
        try:
            return replace(_load(path, config), system=system)
        except ValueError as exc:
            warnings.warn(f"{exc}; regenerating the dataset", RuntimeWarning, stacklevel=2)
    ds = _generate(system, u_arr, actuated, config, backend, env_kwargs.get("substeps"))
    if cache:
        try:
            _save(path, ds)
        except OSError as exc:  # a read-only cache must not break generation
            warnings.warn(f"could not write dataset cache {path}: {exc}", RuntimeWarning, stacklevel=2)
    return ds


def _check_request(n_traj: int, T: int, backend: str, env_kwargs: Mapping[str, object]) -> None:
    """ValueError for a bad size, backend or an env kwarg that a dataset cannot take."""
    if backend not in ("numpy", "compiled"):
        raise ValueError(f"backend must be 'numpy' or 'compiled', got {backend!r}")
    if int(n_traj) != n_traj or n_traj < 1:
        raise ValueError(f"n_traj must be a positive integer, got {n_traj!r}")
    if int(T) != T or T < 2:
        raise ValueError(f"T must be an integer >= 2, got {T!r}")
    allowed = {"obs_noise_std", "actuated_dofs", "substeps"}
    bad = [k for k in env_kwargs if k in ENV_KWARGS and k not in allowed]
    if bad:
        raise ValueError(f"make_dataset does not take env kwarg(s) {bad}")


def _port_input(u: np.ndarray | None, n_traj: int, T: int, m: int) -> np.ndarray:
    """The port input as a finite (n_traj, T-1, m) float64 array (zeros when ``u`` is None)."""
    if u is None:
        return np.zeros((n_traj, T - 1, m))
    u_arr = np.asarray(u, dtype=np.float64)
    try:
        u_arr = np.broadcast_to(u_arr, (n_traj, T - 1, m)).copy()
    except ValueError:
        raise ValueError(f"u must broadcast to (n_traj, T-1, m) = {(n_traj, T - 1, m)}, got {np.shape(u)}") from None
    if not np.isfinite(u_arr).all():
        raise ValueError("u must be finite")
    return u_arr


def _generate(system: System, u_arr: np.ndarray, actuated: tuple[int, ...], config: dict[str, Any], backend: str,
              substeps: int | None) -> Dataset:
    """Integrate the batch the cache key ``config`` describes (seed, size, noise) from sampled initial states."""
    n, (n_traj, steps, _) = system.n, u_arr.shape
    ss = np.random.SeedSequence(config["seed"])
    rng_init, rng_noise, rng_sim = (np.random.default_rng(s) for s in ss.spawn(3))
    x0 = system.sample_initial(rng_init, n_traj)
    # generalized force G u (G = the identity's actuated columns), as a scatter: the same values as
    # u_arr @ G.T for finite u, ~10x faster for the 6-dof particle systems.  Stored (T-1, n, N) so that
    # simulate, which reads one step at a time, gets contiguous rows without a copy.
    u_steps = np.zeros((steps, n, n_traj))
    u_steps[:, list(actuated), :] = u_arr.transpose(1, 2, 0)
    u_sim = u_steps.transpose(2, 0, 1)
    if backend == "compiled":
        from .compiled import simulate_compiled

        traj = simulate_compiled(system, x0, steps, u=u_sim, rng=rng_sim, substeps=substeps)
    else:
        traj = simulate(system, x0, steps, u=u_sim, rng=rng_sim, substeps=substeps)
    q_true, p = traj[..., :n], traj[..., n:]
    noise = config["obs_noise_std"]
    q = q_true + (rng_noise.normal(0.0, noise, q_true.shape) if noise > 0 else 0.0)
    for i in system.angle_dims:
        q[..., i] = wrap(q[..., i])
    return Dataset(config["env_id"], q=q, q_true=q_true, p=p, u=u_arr, damping=_true_damping(system, q_true),
                   dt=float(system.dt), angle_dims=tuple(system.angle_dims), actuated_dofs=actuated, config=config,
                   system=system)


def _true_damping(system: System, q_true: np.ndarray) -> np.ndarray:
    """diag D(q) along the true trajectories, (..., n)."""
    const_d = system.constant_damping()
    if const_d is not None:  # one fill instead of n full-size arrays stacked
        damping = np.empty(q_true.shape)
        damping[...] = np.asarray(const_d, dtype=np.float64)
        return damping
    qs = tuple(np.ascontiguousarray(q_true[..., i]) for i in range(system.n))  # contiguous: faster ufuncs
    return np.stack(np.broadcast_arrays(*system.damping(qs, NUMPY)), -1).astype(np.float64)


@dataclass(frozen=True)
class PortExcitation:
    """A random port input for training data: Gaussian levels (std ``std``, per actuated coordinate) held for
    ``hold`` steps each, from its own seed.

    Free motion (u = 0) fixes only the ratios of a Hamiltonian model's parts: V, M^-1 and D scaled by c, 1/c and c
    give the same trajectories, so a model learned from them can have the wrong input gain M^-1 G.  A model meant
    for control (a filter's process model, a world model for RL) is identified from data whose port is excited.
    """

    std: float
    hold: int = 5
    seed: int = 0

    def __post_init__(self) -> None:
        if not (isinstance(self.std, (int, float)) and math.isfinite(self.std) and self.std >= 0):
            raise ValueError(f"port excitation std must be a finite number >= 0, got {self.std!r}")
        if isinstance(self.hold, bool) or int(self.hold) != self.hold or self.hold < 1:
            raise ValueError(f"port excitation hold must be a positive integer (steps), got {self.hold!r}")
        if isinstance(self.seed, bool) or int(self.seed) != self.seed or self.seed < 0:
            raise ValueError(f"port excitation seed must be an integer >= 0, got {self.seed!r}")

    def signal(self, n_traj: int, T: int, m: int) -> np.ndarray:
        """(n_traj, T - 1, m) piecewise-constant input; the same arguments give the same array."""
        rng = np.random.default_rng(np.random.SeedSequence([int(self.seed), int(n_traj), int(T), int(m)]))
        levels = rng.normal(0.0, float(self.std), (int(n_traj), -(-(int(T) - 1) // int(self.hold)), int(m)))
        return np.repeat(levels, int(self.hold), axis=1)[:, : int(T) - 1]

    def for_env(self, env_id: str, n_traj: int, T: int, **env_kwargs: Any) -> np.ndarray:
        """:meth:`signal` sized for ``env_id``'s actuated coordinates (``actuated_dofs`` among ``env_kwargs``)."""
        n = make_env_system(env_id, **env_kwargs).n
        return self.signal(n_traj, T, len(parse_actuated_dofs(env_kwargs.get("actuated_dofs"), n)))


def split_dataset(ds: Dataset, n_train: int = 1000, n_val: int = 200, n_test: int = 200) -> dict[str, Dataset]:
    """Split consecutive trajectories into train / val / test (paper Sec. 4.1.1)."""
    if n_train + n_val + n_test > ds.n_traj:
        raise ValueError(f"split {n_train}/{n_val}/{n_test} needs {n_train + n_val + n_test} trajectories, "
                         f"have {ds.n_traj}")
    a, b = n_train, n_train + n_val
    return {"train": ds.subset(slice(0, a)), "val": ds.subset(slice(a, b)), "test": ds.subset(slice(b, b + n_test))}


def make_splits(
    env_id: str, n_train: int = 1000, n_val: int = 200, n_test: int = 200, T: int = 200, seed: int = 42, **kwargs: Any
) -> dict[str, Dataset]:
    """The paper's protocol: 1000 / 200 / 200 trajectories of T = 200, dataset seed 42."""
    ds = make_dataset(env_id, n_train + n_val + n_test, T=T, seed=seed, **kwargs)
    return split_dataset(ds, n_train, n_val, n_test)
