"""benchmarks/fragility.py (run by benchmarks/identification_fragility.py): spike detection, perturbation, and a tiny
end-to-end study."""

from __future__ import annotations

import json
from pathlib import Path

import torch

import benchmarks.fragility as fragility


def test_loss_spikes_compare_with_the_running_minimum() -> None:
    hist = [{"epoch": e + 1, "train_loss": v} for e, v in enumerate([8e-8, 5e-9, 6e-9, 7e-8, 4e-7, 3e-7, 4e-9])]
    epochs, jump = fragility.loss_spikes(hist, 3.0)
    assert epochs == [4, 5, 6] and jump == 4e-7 / 5e-9
    assert fragility.loss_spikes(hist[:1], 3.0) == ([], 1.0)


def test_perturbation_is_relative_seeded_and_small() -> None:
    a, b = torch.nn.Linear(3, 4), torch.nn.Linear(3, 4)
    b.load_state_dict(a.state_dict())
    fragility.perturb_(a, 1e-7, 1)
    fragility.perturb_(b, 1e-7, 1)
    for p, q in zip(a.parameters(), b.parameters()):
        assert torch.equal(p, q)
    c = torch.nn.Linear(3, 4)
    ref = {k: v.clone() for k, v in c.state_dict().items()}
    fragility.perturb_(c, 1e-3, 2)
    for k, v in c.state_dict().items():
        assert not torch.equal(v, ref[k]) and torch.allclose(v, ref[k], rtol=1e-2, atol=0)


def test_tiny_study_writes_every_run(tmp_path: Path) -> None:
    out = tmp_path / "frag.json"
    assert fragility.main(["--env", "WindyPendulum-v0", "--perturbations", "1", "--epochs", "1", "--n-train", "16",
                           "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert [o["perturbation"] for o in doc["outcomes"]] == [0, 1]
    assert doc["summary"]["runs"] == 2 and doc["env_id"] == "PHAST/WindyPendulum-v0"
    assert all(-10 < o["damping_r2"] <= 1 for o in doc["outcomes"])
