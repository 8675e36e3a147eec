"""The optimizer's parameter groups, decided in one place for both trainers (the env path and the rig path)."""

from __future__ import annotations

from typing import Any

import torch

from ..world.interfaces import ParamGroupsModel


def relative_parameters(model: torch.nn.Module) -> set[int]:
    """Ids of the parameters whose steps are relative (softplus coefficients that start far from a real rig's value):
    the friction coefficients and a component's ``relative_parameters()`` (e.g. a model file's joint armature)."""
    friction = getattr(model, "friction", None)
    out = {id(p) for p in friction.parameters()} if isinstance(friction, torch.nn.Module) else set()
    for m in model.modules():
        rel = getattr(m, "relative_parameters", None)
        if callable(rel) and m is not model:
            out |= {id(p) for p in rel()}
    return out


def param_groups(model: torch.nn.Module, lr: float, friction_lr_mult: float | None = None) -> list[dict[str, Any]]:
    """The optimizer groups of ``model`` at base learning rate ``lr``.

    The model's own groups (``model.param_groups(lr)``: PHAST's damping network at ``damping_lr_mult`` x lr), else one
    group of its trainable parameters.  With ``friction_lr_mult`` (the rig path,
    :class:`phast_model.train.rig_fit.RigTrainConfig`) every group is split into one group per parameter tensor at
    relative rates:

    * friction coefficients and a component's ``relative_parameters()`` at ``friction_lr_mult`` x the group's lr:
      their softplus makes Adam's steps relative, and at the base lr a coefficient moves by ~e^(lr x steps), too
      little to reach a real joint's level from its start;
    * a small physics coefficient (at most 16 entries, mean |p| < 1) at the group's lr x mean |p|: Adam's steps are
      absolute, and lr 0.02 on a real pendulum's template coefficient (0.21 N m) or on the low-rank mass factor of a
      0.005 kg m^2 inertia is a 10-40% jump per step;
    * networks and O(1) coefficients keep the group's lr.
    """
    if isinstance(model, ParamGroupsModel):
        groups = model.param_groups(lr)
    else:
        groups = [{"params": [p for p in model.parameters() if p.requires_grad], "lr": lr}]
    if friction_lr_mult is None:
        return groups
    rel = relative_parameters(model)
    out = []
    for g in groups:
        for p in g["params"]:
            p_lr = g["lr"] * friction_lr_mult if id(p) in rel else g["lr"]
            if id(p) not in rel and p.numel() <= 16:
                p_lr *= min(1.0, max(float(p.detach().abs().mean()), 1e-3))
            out.append({"params": [p], "lr": p_lr})
    return out
