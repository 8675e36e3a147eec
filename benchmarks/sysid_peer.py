"""MuJoCo's own system identification (``mujoco.sysid``, the ``mujoco[sysid]`` extra) on our recordings format.

A peer for side-by-side comparisons with ``phast-mismatch``: :func:`fit_with_sysid` fits the parameters a MuJoCo user
would pick (per-joint ``armature``, ``damping``, ``frictionloss``; optionally every body ``mass``) of a model file to
recorded joint positions, driven by the recorded controls, and returns the fitted values with sysid's 95% intervals
(:func:`mujoco.sysid.calculate_intervals`) and the fitted model file.

How the recordings are put to sysid:

* the measured signal is ``q``, given to sysid as the joints' qpos state signals (``<joint>_qpos``), not as
  ``jointpos`` sensors: sysid's rollouts stamp the sensor values computed *before* a step with the time *after* it,
  so a sensor comparison would lag the prediction by one timestep (a q error of v h at velocity v); the state is
  stamped right.  sysid still checks that the measured columns match the model's sensor count, so the copy of the
  model it simulates carries one ``jointpos`` sensor per hinge / slide joint (and none of its own);
* each training trajectory is cut into consecutive windows of ``window_s`` seconds (default 1 s, the held-out
  rollout window of the comparison), one sysid sequence each, started from the recorded ``q`` and a velocity from a
  local cubic fit of ``q`` around the window's first sample (sysid takes the initial state as given; open-loop
  rollouts of a whole multi-second recording of a chaotic arm would not fit anything);
* each control ``u[k]`` is held from ``t[k]`` to ``t[k+1]``: it is laid out zero-order-hold on the model's own
  timestep grid before it reaches sysid (sysid resamples controls *linearly* at the timestep, which would smear the
  steps); jittered recorded times ``t`` need no resampling, since sysid samples its prediction at the measured times.

* the residual is sysid's default (each window's q columns divided by the norm of that window's measured q), or with
  ``weighting="plain"`` the q errors as they are (:func:`plain_residual`);
* body masses go through sysid's ``body_inertia_param(..., InertiaType.Mass)`` bounds but a float-taking modifier:
  sysid's own hands a 1-element array to ``MjsBody.mass``, a TypeError under mujoco 4.0.

No torch here: numpy and mujoco only.
"""

from __future__ import annotations

import contextlib
import io
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from phast_model.identify.mjcf_write import joint_attr, set_joint_attr

ParamSet = Literal["joints", "joints+masses"]
#: the joint attributes of the "joints" parameter set
JOINT_ATTRS = ("armature", "damping", "frictionloss")
#: upper bounds of the joint attributes, in units of the joint's diagonal of the mass matrix at qpos0 (M_ii): an
#: armature up to M_ii, a damping up to 20 M_ii /s (a 0.05 s decay), a frictionloss up to 20 M_ii rad/s^2
JOINT_UPPER = {"armature": 1.0, "damping": 20.0, "frictionloss": 20.0}
#: a body mass may move within these multiples of its file value
MASS_RANGE = (0.5, 2.0)
#: half-width (and at least this many samples each side) of the local cubic fit of q that gives each window's
#: initial velocity
VEL_HALFWIDTH_S, VEL_MIN_HALF = 0.04, 4
SENSOR_PREFIX = "sysid_q_"


@dataclass(frozen=True)
class FittedValue:
    """One fitted scalar: ``element`` (joint / body name) ``attr`` of the model file."""

    kind: str  # joint | body
    element: str
    attr: str  # armature | damping | frictionloss | mass
    start: float  # the file's value
    fitted: float
    lower: float
    upper: float
    ci95: float | None  # half-width of sysid's 95% interval (None: not computed; inf: not identifiable)

    @property
    def at_bound(self) -> bool:
        span = self.upper - self.lower
        return bool(min(self.fitted - self.lower, self.upper - self.fitted) <= 1e-3 * span)

    def as_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "element": self.element, "attr": self.attr, "start": self.start,
                "fitted": self.fitted, "lower": self.lower, "upper": self.upper, "ci95": self.ci95,
                "at_bound": self.at_bound}


@dataclass
class SysidResult:
    """What :func:`fit_with_sysid` fitted, how, and the fitted model file's text."""

    params: str
    weighting: str
    values: dict[str, FittedValue]  # by parameter name, "<element>.<attr>"
    xml: str
    wall_s: float
    train_indices: list[int]
    n_windows: int
    window_s: float | None
    timestep: float
    cost_start: float
    cost_final: float
    intervals_error: str | None = None
    optimizer_log: str = ""
    notes: list[str] = field(default_factory=list)

    @property
    def fitted(self) -> dict[str, float]:
        return {k: v.fitted for k, v in self.values.items()}

    def write_xml(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(self.xml)
        return path

    def as_dict(self) -> dict[str, Any]:
        return {"params": self.params, "weighting": self.weighting, "values": {k: v.as_dict() for k, v in self.values.items()},
                "wall_s": self.wall_s, "train_indices": self.train_indices, "n_windows": self.n_windows,
                "window_s": self.window_s, "timestep": self.timestep, "cost_start": self.cost_start,
                "cost_final": self.cost_final, "intervals_error": self.intervals_error, "notes": self.notes,
                "optimizer": [ln for ln in self.optimizer_log.splitlines() if ln.startswith(("Terminated", "total"))]}


@dataclass(frozen=True)
class RecArrays:
    """The recordings as sysid needs them."""

    q: np.ndarray  # (N, T, n)
    u: np.ndarray | None  # (N, T-1, m)
    t: np.ndarray  # (N, T), each row from its own start


# ------------------------------------------------------------------------------------------------------ the inputs


def _sysid() -> Any:
    """``mujoco.sysid``, or an ImportError saying what is missing (its package swallows missing extras)."""
    from mujoco import sysid

    if not hasattr(sysid, "optimize"):
        raise ImportError("mujoco.sysid is not usable: install the extra, pip install 'mujoco[sysid]'")
    return sysid


def recordings_arrays(recordings: Mapping[str, Any]) -> RecArrays:
    """q, u (trimmed to T-1 samples) and per-trajectory times t from a recordings dict (``dt`` or ``t``)."""
    q = np.asarray(recordings["q"], dtype=float)
    if q.ndim == 2:
        q = q[None]
    N, T = q.shape[:2]
    u = recordings.get("u")
    if u is not None:
        u = np.asarray(u, dtype=float)
        u = (u[None] if u.ndim == 2 else u)[:, : T - 1]
    if recordings.get("t") is not None:
        t = np.broadcast_to(np.asarray(recordings["t"], dtype=float), (N, T)).copy()
    else:
        t = np.broadcast_to(np.arange(T) * float(recordings["dt"]), (N, T)).copy()
    return RecArrays(q=q, u=u, t=t - t[:, :1])


def joint_names(model: Any) -> list[str]:
    """The model's joints in qpos order (hinge / slide only)."""
    import mujoco

    ok = {int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)}
    if model.nq != model.nv or any(int(model.jnt_type[j]) not in ok for j in range(model.njnt)):
        raise ValueError("fit_with_sysid takes models of hinge and slide joints only")
    order = np.argsort(model.jnt_qposadr)
    return [model.joint(int(j)).name for j in order]


def sensor_spec(xml_path: str | Path) -> Any:
    """The model file's spec with one ``jointpos`` sensor per joint (qpos order) and no other sensor."""
    import mujoco

    spec = mujoco.MjSpec.from_file(str(xml_path))
    for s in list(spec.sensors):
        spec.delete(s)
    for name in joint_names(spec.compile()):
        spec.add_sensor(name=SENSOR_PREFIX + name, type=mujoco.mjtSensor.mjSENS_JOINTPOS,
                        objtype=mujoco.mjtObj.mjOBJ_JOINT, objname=name)
    return spec


def initial_velocity(q: np.ndarray, t: np.ndarray, i: int, half_s: float = VEL_HALFWIDTH_S) -> np.ndarray:
    """dq/dt at sample ``i`` from a least-squares cubic through the samples within ``half_s`` of it (at least
    :data:`VEL_MIN_HALF` each side; one-sided at the recording's ends)."""
    dt = float(np.median(np.diff(t)))
    h = max(VEL_MIN_HALF, int(round(half_s / dt)))
    lo, hi = max(0, i - h), min(len(t), i + h + 1)
    if hi - lo < 2 * h + 1:  # at an end: a one-sided window of the same length
        lo, hi = (0, min(len(t), 2 * h + 1)) if lo == 0 else (max(0, len(t) - 2 * h - 1), len(t))
    tau = t[lo:hi] - t[i]
    A = np.stack([tau**p for p in range(4)], axis=1)
    coef, *_ = np.linalg.lstsq(A, q[lo:hi], rcond=None)
    return coef[1]


def zoh_control(tau: np.ndarray, u: np.ndarray, timestep: float) -> tuple[np.ndarray, np.ndarray]:
    """Controls ``u[k]`` held over ``[tau[k], tau[k+1])`` laid out on the grid ``0, h, ..., K h`` (K h <= tau[-1]).

    The grid's last time is nudged so that sysid's own ``resample(target_dt=h)`` reproduces exactly this grid."""
    K = int(np.floor(tau[-1] / timestep + 1e-9))
    grid = np.arange(K + 1) * timestep
    idx = np.clip(np.searchsorted(tau[:-1], grid + 1e-9 * timestep, side="right") - 1, 0, len(u) - 1)
    for _ in range(8):  # ceil(grid[-1] / h) must come out as K, not K + 1
        if int(np.ceil((grid[-1] - grid[0]) / timestep)) == K:
            break
        grid[-1] = np.nextafter(grid[-1], -np.inf)
    return grid, u[idx]


def window_starts(t: np.ndarray, window_s: float | None) -> list[tuple[int, int]]:
    """Consecutive windows ``[start, end]`` (sample indices, end inclusive) of ``window_s`` seconds (None: whole)."""
    if window_s is None:
        return [(0, len(t) - 1)]
    out, s = [], 0
    while True:
        e = int(np.searchsorted(t, t[s] + window_s + 1e-9, side="right")) - 1
        if e - s < 3 or t[e] - t[s] < 0.5 * window_s:
            break
        out.append((s, e))
        s = e
        if s >= len(t) - 1:
            break
    return out or [(0, len(t) - 1)]


def model_sequences(spec: Any, recs: RecArrays, indices: Sequence[int], window_s: float | None) -> Any:
    """One sysid ``ModelSequences`` holding a sequence per window of each training trajectory."""
    sysid = _sysid()
    model = spec.compile()
    h = float(model.opt.timestep)
    qpos_names = [f"{j}_qpos" for j in joint_names(model)]
    names, states, ctrls, sens = [], [], [], []
    for k in indices:
        q, t = recs.q[k], recs.t[k]
        u = recs.u[k] if recs.u is not None else np.zeros((len(t) - 1, model.nu))
        for s, e in window_starts(t, window_s):
            tau = t[s: e + 1] - t[s]
            names.append(f"traj{k}_t{t[s]:.3f}")
            states.append(sysid.create_initial_state(model, q[s], initial_velocity(q, t, s)))
            grid, ctrl = zoh_control(tau, u[s:e], h)
            ctrls.append(sysid.TimeSeries(grid, ctrl))
            sens.append(sysid.TimeSeries.from_names(tau, q[s: e + 1], model, names=qpos_names))
    return sysid.ModelSequences("model", spec, names, states, ctrls, sens)


# ---------------------------------------------------------------------------------------------------- parameters


def _set_mass(spec: Any, body: str, value: float) -> None:
    """sysid's own mass modifier (``apply_body_inertia`` for ``InertiaType.Mass``) hands the 1-element array to
    ``MjsBody.mass``, which mujoco 4.0 refuses (TypeError): the same call with a float."""
    _sysid().model_modifier.apply_body_mass_ipos(spec, body, mass=float(value))


def parameter_dict(spec: Any, params: ParamSet, upper: Mapping[str, float] | None = None) -> Any:
    """sysid Parameters of ``params``: ``<joint>.<attr>`` with bounds [0, JOINT_UPPER * M_ii] (``upper`` overrides
    the multiples by attribute), and ``<body>.mass`` within :data:`MASS_RANGE` of the file value."""
    import mujoco

    sysid = _sysid()
    if params not in ("joints", "joints+masses"):
        raise ValueError(f"params must be 'joints' or 'joints+masses', got {params!r}")
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    M = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, M)
    mult = {**JOINT_UPPER, **(upper or {})}
    pd = sysid.ParameterDict()
    for name in joint_names(model):
        d = int(model.joint(name).dofadr[0])
        Mii = float(M[d, d])
        for attr in JOINT_ATTRS:
            v0 = joint_attr(spec.joint(name), attr)
            hi = max(mult[attr] * Mii, 2.0 * v0, 1e-9)
            pd.add(sysid.Parameter(f"{name}.{attr}", nominal=v0, min_value=0.0, max_value=hi,
                                   modifier=lambda s, p, n=name, a=attr: set_joint_attr(s.joint(n), a, p.value[0])))
    if params == "joints+masses":
        for b in range(1, model.nbody):
            body = model.body(b).name
            if model.body_mass[b] <= 0 or not body:
                continue
            p = sysid.body_inertia_param(spec, model, body, inertia_type=sysid.InertiaType.Mass,
                                         mass_bound_mult=np.array(MASS_RANGE), param_name=f"{body}.mass",
                                         modifier=lambda s, p, b=body: _set_mass(s, b, p.value[0]))
            pd.add(p)
    return pd.move_off_bounds(fraction=0.02)


def _kind_element_attr(name: str) -> tuple[str, str, str]:
    element, attr = name.rsplit(".", 1)
    return ("body" if attr == "mass" else "joint"), element, attr


def fitted_xml(xml_path: str | Path, opt_params: Any) -> str:
    """The model file (without the sysid sensors) with the fitted values written in."""
    import mujoco

    spec = mujoco.MjSpec.from_file(str(xml_path))
    for p in opt_params.values():
        p.apply_modifier(spec)
    spec.compile()
    return spec.to_xml()


# ------------------------------------------------------------------------------------------------------- the fit

Weighting = Literal["sysid", "plain", "wrapped"]


def plain_residual(params: Any, pred_sensordata: Any, measured_sensordata: Any, model: Any, return_pred_all: bool,
                   state: np.ndarray | None = None, **_: Any) -> tuple[np.ndarray, Any, Any]:
    """A sysid ``modify_residual``: measured q minus the rolled-out qpos at the measured times, in radians / metres,
    unweighted.  sysid's default divides each window's residual column by the norm of that window's measured q, which
    weights a window where a joint stays near 0 (or an angle that hovers near 0) tens of times more than one that
    swings about pi; the held-out score is a plain RMSE."""
    del params, pred_sensordata, return_pred_all
    sysid = _sysid()
    assert state is not None
    pred = sysid.TimeSeries(state[:, 0], state[:, 1: 1 + model.nq], measured_sensordata.signal_mapping)
    meas = sysid.signal_modifier.apply_delayed_ts_window(measured_sensordata, pred, 0.0, 0.0)
    pred = pred.resample(meas.times)
    return meas.data - pred.data, pred, meas


def wrapped_residual(params: Any, pred_sensordata: Any, measured_sensordata: Any, model: Any,
                     return_pred_all: bool, state: np.ndarray | None = None, **kw: Any) -> tuple[np.ndarray, Any, Any]:
    """:func:`plain_residual` with every hinge's error wrapped to (-pi, pi], as the held-out RMSE wraps it: a window
    whose rollout goes over the top a turn early counts as at most half a turn off, not whole turns (which otherwise
    dominate the least squares on a real arm that swings over the top)."""
    import mujoco

    d, pred, meas = plain_residual(params, pred_sensordata, measured_sensordata, model, return_pred_all, state, **kw)
    hinge = np.asarray(model.jnt_type)[: d.shape[-1]] == int(mujoco.mjtJoint.mjJNT_HINGE)
    d = np.where(hinge, np.mod(d + np.pi, 2 * np.pi) - np.pi, d)
    return d, pred, meas



def _cost(residual_fn: Any, x: np.ndarray, params: Any) -> tuple[float, list[np.ndarray]]:
    res, _, _ = residual_fn(x, params)
    r = np.concatenate(res)
    return float(0.5 * r @ r), res


def _intervals(residual_fn: Any, opt_params: Any) -> tuple[np.ndarray | None, str | None]:
    """sysid's 95% half-widths from a finite-difference Jacobian at the optimum (None, reason: when it fails)."""
    from mujoco import minimize

    sysid = _sysid()
    try:
        x = opt_params.as_vector()
        lo, hi = opt_params.get_bounds()
        p = opt_params.copy()

        def f(z: np.ndarray) -> np.ndarray:
            res, _, _ = residual_fn(z, p)
            return np.concatenate(res)

        r = f(x)
        eps = 1e-6  # frictionloss acts through the constraint solver: a step far above its tolerance
        jac, _ = minimize.jacobian_fd(residual=f, x=x.reshape(-1, 1), r=r.reshape(-1, 1), eps=eps, n_res=0,
                                      bounds=[lo.reshape(-1, 1), hi.reshape(-1, 1)])
        _, res_star = _cost(residual_fn, x, p)
        _, ci = sysid.calculate_intervals(res_star, np.asarray(jac))
        return np.asarray(ci, dtype=float), None
    except Exception as exc:  # noqa: BLE001 - a report, not a crash: the fit stands without intervals
        return None, f"{type(exc).__name__}: {exc}"


def fit_with_sysid(xml_path: str | Path, recordings: Mapping[str, Any], train_indices: Sequence[int],
                   params: ParamSet = "joints", window_s: float | None = 1.0, max_iters: int = 50,
                   intervals: bool = True, n_threads: int = 1, upper: Mapping[str, float] | None = None,
                   weighting: Weighting = "sysid") -> SysidResult:
    """Fit ``params`` of the model file to the training trajectories of ``recordings`` with ``mujoco.sysid``.

    ``recordings``: ``q`` (N, T, n) joint positions in qpos order, ``u`` (N, T-1 or T, m) actuator controls held
    over each interval, and ``dt`` or per-sample times ``t`` (T,) / (N, T) (jitter allowed).  ``params``:
    ``"joints"`` (per-joint armature, damping, frictionloss) or ``"joints+masses"`` (and every body mass).
    ``window_s``: length of the rollout windows the trajectories are cut into (None: whole trajectories).
    ``weighting``: ``"sysid"`` (its default residual: each window's columns divided by the norm of its measured q)
    or ``"plain"`` (:func:`plain_residual`, q errors as they are) or ``"wrapped"`` (:func:`wrapped_residual`: hinge
    errors wrapped, like the held-out RMSE).
    """
    sysid = _sysid()
    t0 = time.time()
    recs = recordings_arrays(recordings)
    spec = sensor_spec(xml_path)
    timestep = float(spec.compile().opt.timestep)
    seqs = model_sequences(spec, recs, list(train_indices), window_s)
    pd = parameter_dict(spec, params, upper)
    extra = {"plain": {"modify_residual": plain_residual},
             "wrapped": {"modify_residual": wrapped_residual}}.get(weighting, {})
    residual_fn = sysid.build_residual_fn(models_sequences=[seqs], n_threads=n_threads, **extra)
    cost0, _ = _cost(residual_fn, pd.as_vector(), pd.copy())
    log = io.StringIO()
    with contextlib.redirect_stdout(log):  # the backend prints every iteration
        # MuJoCo's least squares; FD step well above the constraint solver's tolerance (frictionloss); scaled by |J|
        opt_params, _ = sysid.optimize(initial_params=pd, residual_fn=residual_fn, optimizer="mujoco", verbose=False,
                                       max_iters=max_iters, output=log, x_scale="jac", eps=1e-6)
    cost1, _ = _cost(residual_fn, opt_params.as_vector(), opt_params.copy())
    ci, err = _intervals(residual_fn, opt_params) if intervals else (None, "not requested")
    lo, hi = opt_params.get_bounds()
    values = {}
    for i, name in enumerate(opt_params.keys()):
        kind, element, attr = _kind_element_attr(name)
        values[name] = FittedValue(kind, element, attr, float(opt_params[name].nominal[0]),
                                   float(opt_params[name].value[0]), float(lo[i]), float(hi[i]),
                                   None if ci is None else float(ci[i]))
    at_bound = [k for k, v in values.items() if v.at_bound]
    notes = [f"at a bound: {', '.join(at_bound)}"] if at_bound else []
    return SysidResult(params=params, weighting=weighting, values=values, xml=fitted_xml(xml_path, opt_params), wall_s=time.time() - t0,
                       train_indices=list(train_indices), n_windows=len(seqs.measured_rollout), window_s=window_s,
                       timestep=timestep, cost_start=cost0, cost_final=cost1, intervals_error=err,
                       optimizer_log=log.getvalue(), notes=notes)
