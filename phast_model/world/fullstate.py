"""Full-state PHAST: the port-Hamiltonian core on observed (q, p), for the paper's Table 25 ablation.

In the q-only setting the observer infers p from the position history (paper Sec. 3.1).  When p is
measured too (the full-state ablation of Appendix H.1, where DHNN is the baseline), the observer
and canonicalizer are not needed: the state (q_t, p_t) is read off the data and the same Strang
core (Eq. 42 / 78) advances it.  :class:`FullStatePHAST` wraps a regime-built :class:`~phast_model.world.model.PHAST`
(KNOWN / PARTIAL / UNKNOWN, :func:`phast_model.world.regimes.build_model`) and exposes the
``ForecastModel`` interface on the stacked state ``x = (q, p)`` of shape (B, T, 2n), the input
format of :func:`phast_model.bench.runner.full_state_view` and of DHNN.  The wrapped model's
observer is frozen and not counted (it is never called).
"""

from __future__ import annotations

from typing import Any

import torch

from .interfaces import ForecastModel, wrap_angles
from .model import PHAST


class FullStatePHAST(ForecastModel):
    """PHAST on (q, p): next-step predictions x_t -> x_{t+1} = Strang step of the core (no observer)."""

    def __init__(self, phast: PHAST) -> None:
        if not isinstance(phast, PHAST) or not phast.system.hamiltonian_system:
            raise ValueError("FullStatePHAST needs a port-Hamiltonian PHAST model (its core advances (q, p))")
        super().__init__(2 * phast.n, phast.m, phast.angle_dims)
        self.phast = phast
        self.phast.observer.requires_grad_(False)  # unused with p observed: neither trained nor counted
        self.loss_skip = 0  # every step has its state: no observer warm-up

    @property
    def damping(self):  # noqa: ANN201
        return self.phast.damping

    def damping_diag(self, x: torch.Tensor) -> torch.Tensor:
        """Diagonal of the learned D(q) at the positions of x = (q, p): (..., n)."""
        return self.phast.damping_diag(x[..., : self.phast.n])

    def param_groups(self, lr: float) -> list[dict[str, Any]]:
        return self.phast.param_groups(lr)

    def _split(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        if x.shape[-1] != self.n:
            raise ValueError(f"full-state input must have 2n = {self.n} columns (q, p), got {x.shape[-1]}")
        x = x.to(next(self.phast.core.parameters()).dtype)
        n = self.phast.n
        return x[..., :n], x[..., n:]

    def _step(self, q: torch.Tensor, p: torch.Tensor, u: torch.Tensor | None) -> torch.Tensor:
        q1, p1 = self.phast.step(q, p, u)  # Strang step of the core with port force G u (Eq. 42 / 78)
        return torch.cat([wrap_angles(q1, self.phast.angle_dims), p1], -1)

    def forward(self, x: torch.Tensor, u: torch.Tensor | None = None) -> torch.Tensor:
        """Teacher-forced next states for every t at once: (B, T, 2n) -> (B, T, 2n)."""
        q, p = self._split(x)
        u = None if u is None else self.pad_u(u.to(q.dtype), q.shape[1])
        return self._step(q, p, u)

    @torch.no_grad()
    def rollout(self, x_burn: torch.Tensor, u: torch.Tensor | None, H: int) -> torch.Tensor:
        """Open loop from the last burn-in state, O(H): (B, K, 2n) -> (B, H, 2n)."""
        q, p = self._split(x_burn[:, -1])
        K = x_burn.shape[1]
        out = []
        for h in range(H):
            ut = None if u is None or K - 1 + h >= u.shape[1] else u[:, K - 1 + h].to(q.dtype)
            x = self._step(q, p, ut)
            q, p = x[..., : self.phast.n], x[..., self.phast.n:]
            out.append(x)
        return torch.stack(out, 1)
