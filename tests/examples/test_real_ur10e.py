"""examples/real_ur10e_mismatch.py (issue 51, item 2), run as a script: a synthetic dataset_ur10e/ in the published
layout (no header; 31 or 19 columns; a truncated row, a NaN row, a payload run) is read, converted with the drive gains
and written as a log set (fast); the real dataset when ``PHAST_UR10E_DATA`` names a checkout of
github.com/shamilmamedov/dynamic_calibration."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests import ROOT

SCRIPT = ROOT / "examples" / "real_ur10e_mismatch.py"
JOINTS = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint")
GAINS = np.array([10.0000, 10.6956, 8.4566, 9.0029, 9.4800, 10.1232])


def _urdf() -> str:
    """A 6-joint arm under the UR10e's joint names (±2 pi, the elbow ±pi), a mesh file that is not there."""
    links = "".join(f'<link name="l{k}"><visual><geometry><mesh filename="package://x/l{k}.dae"/></geometry></visual>'
                    f'<inertial><origin xyz="0 0 0.1"/><mass value="{2.0 - 0.2 * k}"/>'
                    '<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>' for k in range(7))
    joints = "".join(f'<joint name="{name}" type="revolute"><parent link="l{k}"/><child link="l{k + 1}"/>'
                     f'<origin xyz="0 0 0.2"/><axis xyz="{"0 0 1" if k in (0, 5) else "0 1 0"}"/>'
                     f'<limit lower="{-3.14159 if k == 2 else -6.28319}" upper="{3.14159 if k == 2 else 6.28319}" effort="100" '
                     'velocity="3"/></joint>' for k, name in enumerate(JOINTS))
    return f'<robot name="ur10e">{links}{joints}</robot>'


def _run_rows(L: int, seed: int, columns: int) -> list[str]:
    """Rows of a UR10e log as published: t, q1..6, qd1..6, i1..6 [, i_des1..6, tau_des1..6]."""
    rng = np.random.default_rng(seed)
    t = 100.0 * seed + np.concatenate([[0.0], np.cumsum(rng.choice([0.010, 0.011, 0.012], L - 1))])
    q = 0.5 * np.sin(1.5 * t[:, None] + np.arange(6)) + np.array([0, -1.57, 0, -1.57, 0, 0])
    qd = 0.75 * np.cos(1.5 * t[:, None] + np.arange(6))
    cur = rng.normal(0.0, 1.0, (L, 6))
    extra = rng.normal(0.0, 1.0, (L, 12))[:, : columns - 19]
    data = np.concatenate([t[:, None], q, qd, cur, extra], axis=1)
    return [",".join(f"{x:.4f}" for x in row) for row in data]


@pytest.fixture
def dataset(tmp_path: Path) -> Path:
    root = tmp_path / "dynamic_calibration"
    ident, valid = root / "dataset_ur10e" / "identification_data", root / "dataset_ur10e" / "validation_data"
    ident.mkdir(parents=True)
    valid.mkdir(parents=True)
    (root / "URe" / "urdf").mkdir(parents=True)
    (root / "URe" / "urdf" / "ur10e.urdf").write_text(_urdf())
    (ident / "ur-19_09_27-11_28_22.csv").write_text("\n".join(_run_rows(120, 1, 19)) + "\n")  # the 2019 layout
    rows = _run_rows(160, 2, 31)
    rows[-1] = ",".join(rows[-1].split(",")[:20]) + ","  # the logger cut the last row off
    (ident / "ur-20_02_19_15harm50sec.csv").write_text("\n".join(rows) + "\n")
    rows = _run_rows(140, 3, 31)
    cells = rows[70].split(",")
    rows[70] = ",".join(cells[:3] + ["nan"] + cells[4:])  # a value that is not finite
    (ident / "ur-20_02_05-20sec_8harm.csv").write_text("\n".join(rows) + "\n")
    (ident / "ur-20_01_31-load.csv").write_text("\n".join(_run_rows(100, 4, 31)) + "\n")  # a payload
    (valid / "ur-20_01_17-ptp_10_points.csv").write_text("\n".join(_run_rows(150, 5, 31)) + "\n")
    (root / "UR10E_parameters.txt").write_text(_parameters(), encoding="utf-8")
    return root


#: the identified model in the published format: per link [Ixx Ixy Ixz Iyy Iyz Izz mx my mz m] about the link frame
LINK = [0.1, 0.0, 0.0, 0.1, 0.0, 0.02, 0.0, 0.0, 0.3, 1.5]
DRIVES = [0.0, 3.0, 0.5, 0.07, 0.2, 0.4]
FRICTION = [[20.0 - 3 * k, 12.0 - 2 * k, 0.1] for k in range(6)]  # Fv, Fc, offset per joint


def _parameters() -> str:
    vec = lambda name, xs: f"{name} = [" + "\t".join(f"{x:.6g}" for x in xs) + "]"  # noqa: E731
    return "\n".join(["drvGains - коэффициенты передачи двигателей", "", vec("drvGains", GAINS), "",
                      vec("pi_drvs", DRIVES), "", vec("pi_frcn", sum(FRICTION, [])), "", vec("pi_rgd", LINK * 6), ""])


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, cwd=ROOT, timeout=300,
                          env={**os.environ, "OMP_NUM_THREADS": "1"})


def test_the_published_layout_is_read_as_it_comes(dataset: Path, tmp_path: Path) -> None:
    done = _run("--data", str(dataset), "--out", str(tmp_path / "out"), "--convert-only")
    assert done.returncode == 0, done.stderr
    facts = json.loads((tmp_path / "out" / "runs.json").read_text())
    assert facts["train"] == ["ur-19_09_27-11_28_22.csv", "ur-20_02_05-20sec_8harm.csv"]
    assert facts["held_out"] == ["ur-20_01_17-ptp_10_points.csv", "ur-20_02_19_15harm50sec.csv"]
    assert facts["left_out"] == ["ur-20_01_31-load.csv: payload"]
    assert facts["rows_dropped"] == {"truncated": 1, "not_finite": 1, "isolated": 0}
    assert facts["rows_dropped_per_log"]["ur-20_02_19_15harm50sec.csv"]["truncated"] == 1
    with np.load(tmp_path / "out" / "recordings.npz") as z:
        assert [str(x) for x in z["coordinate_names"]] == list(JOINTS)
        published = np.loadtxt(dataset / "dataset_ur10e" / "identification_data" / "ur-19_09_27-11_28_22.csv", delimiter=",")
        np.testing.assert_allclose(z["u_0"], published[:, 13:19] * GAINS)  # u = drive gain x measured current
        np.testing.assert_allclose(z["q_0"], published[:, 1:7])
    assert "2 rows dropped: 1 truncated, 1 not finite" in done.stdout


def test_gains_are_a_model_choice_and_bad_options_exit_2(dataset: Path, tmp_path: Path) -> None:
    done = _run("--data", str(dataset), "--out", str(tmp_path / "a"), "--convert-only", "--drive-gains", "[1, 1, 1, 1, 1, 1]",
                "--current-scale", "2", "--max-runs", "1", "--max-seconds", "0.8")
    assert done.returncode == 0, done.stderr
    with np.load(tmp_path / "a" / "recordings.npz") as z:
        published = np.loadtxt(dataset / "dataset_ur10e" / "identification_data" / "ur-19_09_27-11_28_22.csv", delimiter=",")
        assert len(z["u_0"]) < len(published)
        np.testing.assert_allclose(z["u_0"], 2 * published[: len(z["u_0"]), 13:19])
    assert json.loads((tmp_path / "a" / "runs.json").read_text())["drive_gains"] == [2.0] * 6
    bad = _run("--data", str(dataset), "--out", str(tmp_path / "b"), "--convert-only", "--drive-gains", "[1, 2]")
    assert bad.returncode == 2 and "--drive-gains must be 6 finite numbers" in bad.stderr
    missing = _run("--data", str(tmp_path / "nowhere"), "--out", str(tmp_path / "c"))
    assert missing.returncode == 2 and "shamilmamedov/dynamic_calibration" in missing.stderr


@pytest.mark.slow  # a whole analysis of a 6-joint arm (about a minute)
def test_the_authors_model_is_scored_beside_the_answer(dataset: Path, tmp_path: Path) -> None:
    """Their identified model (UR10E_parameters.txt) written as MJCF: link mass, centre of mass and inertia about it,
    drive inertia as armature, Fv as damping, Fc as frictionloss; scored on the held-out runs as fit.authors."""
    mujoco = pytest.importorskip("mujoco")
    done = _run("--data", str(dataset), "--out", str(tmp_path / "out"), "--max-runs", "1", "--max-seconds", "0.6",
                "--holdout", "ur-20_01_17-ptp_10_points", "--rollout-window", "0.3")
    assert done.returncode == 0, done.stderr + done.stdout
    m = mujoco.MjModel.from_xml_path(str(tmp_path / "out" / "authors_model.xml"))
    np.testing.assert_allclose(m.dof_armature, DRIVES)
    np.testing.assert_allclose(m.dof_damping, [f[0] for f in FRICTION])
    np.testing.assert_allclose(m.dof_frictionloss, [f[1] for f in FRICTION])
    mass, com = LINK[9], np.array(LINK[6:9]) / LINK[9]
    moved = [m.jnt_bodyid[j] for j in range(6)]
    np.testing.assert_allclose(m.body_mass[moved], mass)
    np.testing.assert_allclose(m.body_ipos[moved], np.tile(com, (6, 1)), atol=1e-12)
    about_com = sorted([LINK[0] - mass * com[2] ** 2, LINK[3] - mass * com[2] ** 2, LINK[5]])  # parallel axes
    np.testing.assert_allclose(np.sort(m.body_inertia[moved], axis=1), np.tile(about_com, (6, 1)), atol=2e-6)
    report = json.loads((tmp_path / "out" / "report" / "report.json").read_text())
    assert {"nominal", "augmented", "authors"} <= set(report["fit"])


def test_degrees_in_a_log_are_refused(dataset: Path, tmp_path: Path) -> None:
    path = dataset / "dataset_ur10e" / "identification_data" / "ur-20_02_05-20sec_8harm.csv"
    data = np.loadtxt(path, delimiter=",")
    data[:, 1:7] = np.degrees(data[:, 1:7])
    np.savetxt(path, data, delimiter=",", fmt="%.4f")
    done = _run("--data", str(dataset), "--out", str(tmp_path / "out"), "--convert-only")
    assert done.returncode == 2 and "looks like degrees" in done.stderr


REAL = os.environ.get("PHAST_UR10E_DATA")


@pytest.mark.skipif(not REAL, reason="the real UR10e dataset: set PHAST_UR10E_DATA to a checkout of the GitHub repository "
                                     "shamilmamedov/dynamic_calibration (or pass --data to examples/real_ur10e_mismatch.py)")
def test_the_real_dataset_as_published(tmp_path: Path) -> None:
    done = _run("--data", str(REAL), "--out", str(tmp_path / "out"), "--convert-only", "--with-payload")
    assert done.returncode == 0, done.stderr
    facts = json.loads((tmp_path / "out" / "runs.json").read_text())
    assert facts["rows_dropped_per_log"]["ur-19_09_27-11_32_02.csv"] == {"truncated": 0, "not_finite": 0, "isolated": 20}
    assert facts["rows_dropped_per_log"]["ur-20_02_19_15harm50secLoad.csv"] == {"truncated": 1, "not_finite": 0, "isolated": 10}
