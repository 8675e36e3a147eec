"""Logs as they come (phast_model.identify.logs, issue 51): logs of different lengths in .npz / .csv / a folder, cut
into equal-length pieces that cover every sample; truncated, non-finite and garbage rows dropped and counted; whole logs
held out; equal-length recordings untouched (fast)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from phast_model.identify.logs import MAX_PIECE_SAMPLES, piece_size, piece_starts, read_rows, repeated_samples
from phast_model.identify.recordings import MIN_SAMPLES, load_raw, validate
from phast_model.identify.split import split

DT = 0.01


def _log(L: int, seed: int, n: int = 1, phase: float = 0.0) -> np.ndarray:
    """A smooth swing of L samples (n coordinates), small noise."""
    t = np.arange(L) * DT
    rng = np.random.default_rng(seed)
    return np.stack([0.8 * np.sin(2.0 * t + phase + j) for j in range(n)], axis=1) + rng.normal(0, 1e-4, (L, n))


def _times(L: int, seed: int, start: float = 0.0) -> np.ndarray:
    """Jittered logger times (steps 0.8..1.2 dt)."""
    return start + np.concatenate([[0.0], np.cumsum(DT * np.random.default_rng(seed).uniform(0.8, 1.2, L - 1))])


# --------------------------------------------------------------------------- pieces
@settings(max_examples=200, deadline=None)
@given(length=st.integers(2, 3000), size=st.integers(2, 400))
def test_pieces_cover_every_sample_and_share_boundaries(length, size):
    starts = piece_starts(length, size)
    if length < size:
        assert starts == []
        return
    covered = np.zeros(length, dtype=int)
    for s in starts:
        covered[s:s + size] += 1
    assert covered.min() >= 1, "a sample is in no piece"
    assert starts[0] == 0 and starts[-1] + size == length
    gaps = np.diff(starts)
    assert np.all(gaps[:-1] == size - 1) and (not len(gaps) or 1 <= gaps[-1] <= size - 1)  # shared boundary samples
    assert repeated_samples(length, size) == int(np.sum(covered - 1)) - (len(starts) - 1)


@settings(max_examples=40, deadline=None)
@given(lengths=st.lists(st.integers(MIN_SAMPLES, 700), min_size=1, max_size=5), seed=st.integers(0, 10_000))
def test_a_random_log_set_is_cut_into_pieces_holding_every_sample(lengths, seed):
    logs = [_log(L, seed + k) for k, L in enumerate(lengths)]
    rec = validate({"q": logs, "t": [_times(L, seed + k, 3.0 * k) for k, L in enumerate(lengths)]}, 1, ())
    size = rec.T
    assert MIN_SAMPLES <= size <= min(min(lengths), MAX_PIECE_SAMPLES)
    assert rec.origin is not None and rec.meta["logs"]["rows_dropped"] == {"truncated": 0, "not_finite": 0, "isolated": 0}
    for k, L in enumerate(lengths):
        mine = np.flatnonzero(rec.origin[:, 0] == k)
        seen = np.zeros(L, dtype=bool)
        for i in mine:
            first, last = rec.origin[i, 1:]
            assert last - first + 1 == size
            np.testing.assert_array_equal(rec.q[i, :, 0], logs[k][first:last + 1, 0])  # no angle dims: as recorded
            seen[first:last + 1] = True
        assert seen.all()
    assert rec.meta["logs"]["rows"] == list(lengths)


def test_piece_size_keeps_the_shortest_log_whole_and_repeats_few_samples():
    assert MIN_SAMPLES <= piece_size([120, 300, 77], MIN_SAMPLES) <= 77
    size = piece_size([594, 1119, 2000], MIN_SAMPLES)
    assert 297 <= size <= 594
    assert sum(repeated_samples(L, size) for L in (594, 1119, 2000)) <= sum(repeated_samples(L, 594) for L in (594, 1119, 2000))
    assert piece_size([5000], MIN_SAMPLES) <= MAX_PIECE_SAMPLES


# --------------------------------------------------------------------------- formats
def test_ragged_npz_with_per_log_keys(tmp_path):
    lengths = (150, 260, 90)
    arrays = {}
    for k, L in enumerate(lengths):
        arrays[f"q_{k}"] = _log(L, k, n=2)
        arrays[f"t_{k}"] = _times(L, k, 10.0 * k)
        arrays[f"u_{k}"] = np.random.default_rng(k).normal(size=(L - 1, 2))
    np.savez(tmp_path / "logs.npz", **arrays, log_names=np.array(["a", "b", "c"]))
    raw, src = load_raw(tmp_path / "logs.npz")
    assert isinstance(raw["q"], list) and len(raw["q"]) == 3
    rec = validate(raw, 2, (0, 1), src)
    assert rec.u is not None and rec.u.shape == (rec.n_traj, rec.T - 1, 2) and rec.t is not None
    assert rec.meta["logs"]["names"] == ["a", "b", "c"] and sorted(set(rec.log_of.tolist())) == [0, 1, 2]
    i = int(np.flatnonzero(rec.origin[:, 0] == 1)[1])
    first = rec.origin[i, 1]
    np.testing.assert_allclose(rec.u[i], arrays["u_1"][first:first + rec.T - 1])  # u follows its samples
    np.testing.assert_allclose(rec.t[i], arrays["t_1"][first:first + rec.T])


def test_npz_with_object_arrays_names_the_per_log_keys(tmp_path):
    q = np.empty(2, dtype=object)
    q[0], q[1] = np.zeros((50, 1)), np.zeros((60, 1))
    np.savez(tmp_path / "obj.npz", q=q, dt=0.01)
    with pytest.raises(ValueError, match="object arrays .* q_0, q_1"):
        load_raw(tmp_path / "obj.npz")
    rec = validate({"q": list(q), "dt": 0.01}, 1, (0,))  # in memory, a list (or object array) is a log set
    assert rec.meta["logs"]["n_logs"] == 2


def _csv(rows: list[str]) -> str:
    return "\n".join(["traj,t,q0,u0", *rows]) + "\n"


def test_ragged_csv_drops_truncated_and_nan_rows_and_counts_them(tmp_path):
    rows = []
    for k, L in enumerate((120, 200)):
        q, t = _log(L, k), _times(L, k)
        for i in range(L):
            if k == 1 and i == 60:
                rows.append(f"{k},{t[i]:.6f},nan,0.1")  # a non-finite value
            elif k == 1 and i == 150:
                rows.append(f"{k},{t[i]:.6f},{q[i, 0]:.8f}")  # the logger cut the row off
            else:
                rows.append(f"{k},{t[i]:.6f},{q[i, 0]:.8f},0.1")
    (tmp_path / "r.csv").write_text(_csv(rows))
    raw, src = load_raw(tmp_path / "r.csv")
    rec = validate(raw, 1, (0,), src)
    facts = rec.meta["logs"]
    assert facts["rows"] == [120, 200] and facts["rows_used"] == [120, 198]
    assert facts["rows_dropped"] == {"truncated": 1, "not_finite": 1, "isolated": 0}
    assert facts["rows_dropped_per_log"][1] == {"truncated": 1, "not_finite": 1, "isolated": 0}
    assert facts["gaps_bridged"] == 2 and "2 rows dropped: 1 truncated, 1 not finite" in facts["note"]
    assert rec.t is not None and np.max(rec.steps) > 1.5 * DT  # the gap is a longer recorded step, not interpolated


def test_a_folder_of_csv_logs(tmp_path):
    folder = tmp_path / "logs"
    folder.mkdir()
    for k, L in enumerate((80, 130, 55)):
        q, t = _log(L, k), _times(L, k)
        (folder / f"run{k}.csv").write_text("t,q0\n" + "".join(f"{t[i]:.6f},{q[i, 0]:.8f}\n" for i in range(L)))
    raw, src = load_raw(folder)
    rec = validate(raw, 1, (0,), src)
    assert rec.meta["logs"]["names"] == ["run0.csv", "run1.csv", "run2.csv"] and rec.T <= 55
    raw2, _ = load_raw([folder / "run2.csv", folder / "run0.csv"])
    assert validate(raw2, 1, (0,)).meta["logs"]["names"] == ["run2.csv", "run0.csv"]
    with pytest.raises(ValueError, match="no .csv log"):
        load_raw(tmp_path)


def test_equal_length_recordings_are_not_a_log_set(tmp_path):
    q = np.stack([_log(100, k) for k in range(3)])
    rec = validate({"q": q, "dt": DT}, 1, (0,))
    assert rec.origin is None and rec.meta == {}
    rows = [f"{k},{i * DT:.4f},{q[k, i, 0]:.8f}" for k in range(3) for i in range(100)]
    (tmp_path / "r.csv").write_text("traj,t,q0\n" + "\n".join(rows) + "\n")
    raw, _ = load_raw(tmp_path / "r.csv")
    assert isinstance(raw["q"], np.ndarray) and raw["q"].shape == (3, 100, 1)
    with pytest.raises(ValueError, match="NaN.*q_0, q_1"):
        validate({"q": np.where(np.arange(100)[None, :, None] == 5, np.nan, q), "dt": DT}, 1, (0,))


# --------------------------------------------------------------------------- garbage
def test_garbage_rows_are_dropped_and_the_log_bridged_or_split():
    q0, t0 = _log(300, 1), _times(300, 1)
    q = q0.copy()
    q[:6] = [[253.0], [0.0], [-1e200], [31.0], [0.4], [7e259]]  # a logger's start-up garbage
    q[150] = 2.5  # one absurd sample in the middle
    rec = validate({"q": [q, _log(200, 2)], "t": [t0, _times(200, 2)]}, 1, ())
    facts = rec.meta["logs"]
    assert facts["rows_dropped_per_log"][0] == {"truncated": 0, "not_finite": 0, "isolated": 7}
    assert facts["segments"] == [1, 1] and facts["gaps_bridged"] == 1
    assert np.abs(rec.q).max() < 1.0
    untimed = validate({"q": [q, _log(200, 2)], "dt": DT}, 1, ())  # without recorded times a gap splits the log
    assert untimed.meta["logs"]["segments"] == [2, 1] and untimed.t is None


def test_a_file_with_nothing_usable_names_the_first_truncated_row(tmp_path):
    (tmp_path / "short.csv").write_text("traj,t,q0\n0,0,1\n0,0.1\n")
    with pytest.raises(ValueError, match="line 3 has 2 values, the header has 3 columns"):
        load_raw(tmp_path / "short.csv")
    table = read_rows(tmp_path / "short.csv")
    assert table.truncated.tolist() == [False, True] and np.isnan(table.values[1]).all()
    with pytest.raises(ValueError, match=f"no log holds {MIN_SAMPLES} consecutive usable samples"):
        validate({"q": [_log(30, 0)], "dt": DT}, 1, (0,))


# --------------------------------------------------------------------------- held out: whole logs
@pytest.fixture
def log_set():
    lengths = (300, 130, 420, 95)
    return validate({"q": [_log(L, k) for k, L in enumerate(lengths)], "t": [_times(L, k) for k, L in enumerate(lengths)]}, 1, (0,))


def test_holdout_indices_name_logs_and_hold_out_every_piece(log_set):
    train, held, what = split(log_set, 0.3, [0, 2])
    assert set(held.log_of.tolist()) == {0, 2} and set(train.log_of.tolist()) == {1, 3}
    assert held.n_traj == int(np.isin(log_set.log_of, [0, 2]).sum()) and "logs [0, 2]" in what
    with pytest.raises(ValueError, match="4 logs, indices 0..3"):
        split(log_set, 0.3, [4])
    with pytest.raises(ValueError, match="every log"):
        split(log_set, 0.3, [0, 1, 2, 3])


def test_holdout_fraction_holds_out_the_last_logs(log_set):
    train, held, what = split(log_set, 0.3)
    assert set(held.log_of.tolist()) == {3} and not set(train.log_of.tolist()) & {3}


def test_one_log_is_held_out_in_time_without_overlap():
    rec = validate({"q": [_log(2500, 0)], "dt": DT}, 1, (0,), piece_samples=400)
    train, held, what = split(rec, 0.3)
    assert held.n_traj >= 1 and train.n_traj >= 1 and "in time" in what
    assert train.origin[:, 2].max() <= held.origin[:, 1].min()  # at most the boundary sample is shared


def test_windows_and_subsets_keep_the_origin(log_set):
    w = log_set.windows(log_set.T // 2)
    assert w.origin is not None and w.n_traj == len(w.origin)
    assert np.array_equal(log_set.subset(np.array([2, 0])).origin, log_set.origin[[2, 0]])


# --------------------------------------------------------------------------- bad input: units, joint order, limits
def test_angles_in_degrees_are_refused_or_converted_when_declared():
    t = np.arange(400) * DT
    deg = np.degrees(np.stack([1.2 * np.sin(2 * t + k) for k in range(3)]))[..., None]
    with pytest.raises(ValueError, match="angle coordinate 0 looks like degrees"):
        validate({"q": deg, "dt": DT}, 1, (0,))
    with pytest.raises(ValueError, match="looks like degrees"):
        validate({"q": list(deg[:, : 300 + 0]) + [deg[0, :200]], "dt": DT}, 1, (0,))
    rec = validate({"q": deg, "dt": DT, "angle_unit": "deg"}, 1, (0,))
    assert np.max(np.abs(rec.q)) < 1.3
    spinning = validate({"q": deg, "dt": DT, "angle_unit": "rad"}, 1, (0,))  # declared: taken as recorded
    assert np.max(np.abs(spinning.q)) > 50
    assert validate({"q": deg, "dt": DT}, 1, ()).n == 1  # not an angle: nothing to check


def _urdf_joint(name: str, kind: str, parent: str, child: str) -> str:
    limit = '<limit lower="-1.5" upper="1.5" effort="10" velocity="3"/>' if kind == "revolute" else ""
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="0 0 -0.4"/><axis xyz="0 1 0"/>{limit}</joint>')


def _urdf_link(name: str, mass: float, visual: str = "") -> str:
    return (f'<link name="{name}">{visual}<inertial><origin xyz="0 0 -0.2"/><mass value="{mass}"/>'
            f'<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.001"/></inertial></link>')


#: a two-joint arm as a URDF whose mesh file is absent (as in a published robot description): the shoulder's range is
#: -1.5..1.5 rad, the elbow is a continuous joint
ARM = ('<robot name="arm2"><link name="base"/>' + _urdf_link("l1", 1.0)
       + _urdf_link("l2", 0.5, '<visual><geometry><mesh filename="package://arm/l2.dae"/></geometry></visual>')
       + _urdf_joint("shoulder", "revolute", "base", "l1") + _urdf_joint("elbow", "continuous", "l1", "l2") + "</robot>")


@pytest.fixture(scope="module")
def arm(tmp_path_factory):
    pytest.importorskip("mujoco")
    from phast_gym.systems.mjcf import mjcf_system

    path = tmp_path_factory.mktemp("mjcf") / "arm2.urdf"
    path.write_text(ARM)
    return mjcf_system(path)()


def test_joint_order_and_ranges_are_checked_against_the_model(arm):
    q = np.stack([_log(200, k, n=2) for k in range(2)])
    ok = validate({"q": q, "dt": DT, "coordinate_names": ["shoulder", "elbow"]}, 2, (0, 1), model=arm)
    assert "joint_limits_reached" not in ok.meta
    with pytest.raises(ValueError, match=r"joint order \['elbow', 'shoulder'\] does not match the model's \['shoulder', 'elbow'\]"):
        validate({"q": q, "dt": DT, "coordinate_names": ["elbow", "shoulder"]}, 2, (0, 1), model=arm)
    with pytest.raises(ValueError, match="not in the model: \\['wrist'\\]"):
        validate({"q": q, "dt": DT, "coordinate_names": ["shoulder", "wrist"]}, 2, (0, 1), model=arm)
    with pytest.raises(ValueError, match=r"joint 0 \(shoulder\) is recorded at .* outside its range -1.5..1.5"):
        validate({"q": q * 2.5, "dt": DT}, 2, (0, 1), model=arm)
    at = validate({"q": q * 1.86, "dt": DT}, 2, (0, 1), model=arm)  # reaches the shoulder's limit: noted, not refused
    assert at.meta["joint_limits_reached"][0]["joint"] == "shoulder"


def test_rig_training_data_take_a_log_set_and_hold_out_logs():
    from phast_model.train.rig_fit import load_rig_data

    lengths = (300, 180, 240)
    raw = {"q": [_log(L, k) for k, L in enumerate(lengths)], "t": [_times(L, k) for k, L in enumerate(lengths)]}
    data = load_rig_data(raw, "PHAST/Pendulum-v0", holdout=[1])
    assert data.heldout is not None and data.holdout == (1,)
    assert set(data.heldout.log_of.tolist()) == {1} and 1 not in set(data.train.log_of.tolist())


def test_angle_coordinates_are_unwrapped_in_each_piece():
    L = 500
    t = np.arange(L) * DT
    spin = np.angle(np.exp(1j * 3.0 * t))[:, None]  # recorded wrapped: 2 pi jumps are not garbage
    rec = validate({"q": [spin, spin[:300]], "dt": DT}, 1, (0,))
    assert rec.meta["logs"]["rows_dropped"]["isolated"] == 0
    assert np.all(np.abs(np.diff(rec.q[..., 0], axis=1)) < 0.1) and math.isclose(rec.dt, DT)


# --------------------------------------------------------------------------- the tools
def _pendulum_logs(tmp_path, lengths=(300, 220, 260, 150, 300)):
    from phast_model.bench.reality import make_reality

    d = make_reality("PHAST/Pendulum-v0", [], n_traj=len(lengths), T=max(lengths), noise_std=0.002, seed=3)
    arrays = {f"q_{k}": d["q"][k, :L] for k, L in enumerate(lengths)}
    arrays["q_1"] = arrays["q_1"].copy()
    arrays["q_1"][100] = np.nan
    path = tmp_path / "logs.npz"
    np.savez(path, **arrays, dt=d["dt"])
    return path


def test_phast_mismatch_takes_a_log_set_and_reports_what_it_dropped(tmp_path, capsys):
    import json

    from phast_model.cli.mismatch import main

    path = _pendulum_logs(tmp_path)
    assert main(["--sim", "PHAST/Pendulum-v0", "--recordings", str(path), "--holdout-trajectories", "4", "--out",
                 str(tmp_path / "out"), "--quiet", "--no-plots"]) == 0
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    logs = report["data"]["logs"]
    assert logs["n_logs"] == 5 and logs["rows_dropped"]["not_finite"] == 1 and logs["segments"] == [1, 2, 1, 1, 1]
    assert report["fit"]["evaluated_on"].startswith("held-out recordings (logs [4]")
    assert f"Logs: {logs['note']}." in (tmp_path / "out" / "report.md").read_text()  # the reader sees them too
    assert main(["--sim", "PHAST/Pendulum-v0", "--recordings", str(path), "--holdout-trajectories", "5", "--out",
                 str(tmp_path / "bad"), "--quiet"]) == 2
    assert "5 logs, indices 0..4" in capsys.readouterr().err and not (tmp_path / "bad").exists()


def test_phast_mismatch_refuses_degrees_and_a_wrong_joint_order_before_writing(tmp_path, capsys, arm):
    from phast_model.cli.mismatch import main

    q = np.stack([_log(200, k, n=2) for k in range(3)])
    np.savez(tmp_path / "deg.npz", q=np.degrees(q), dt=DT)
    assert main(["--sim", "PHAST/DoublePendulum-v0", "--recordings", str(tmp_path / "deg.npz"), "--out", str(tmp_path / "o1"),
                 "--quiet"]) == 2
    assert "looks like degrees" in capsys.readouterr().err
    model = tmp_path / "arm2.urdf"
    model.write_text(ARM)
    np.savez(tmp_path / "swapped.npz", q=q, dt=DT, coordinate_names=np.array(["elbow", "shoulder"]))
    assert main(["--sim", str(model), "--recordings", str(tmp_path / "swapped.npz"), "--out", str(tmp_path / "o2"), "--quiet"]) == 2
    assert "joint order" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["arm2.urdf", "deg.npz", "swapped.npz"]
