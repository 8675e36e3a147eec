"""The paper's reported numbers as the harness reads them (Tables 3, 4, 17-25; mean, std over 5 seeds).

Every comparison the harness prints (gain, ratio to the paper's PHAST) reads from :data:`PAPER`, the
paper rows of the per-env registry :data:`phast_model.world.envinfo.ENV_INFO`, where every paper number is typed.
"""

from __future__ import annotations

from phast_model.world.envinfo import ENV_INFO, PAPER_FULL_STATE, PaperRow

#: env id -> the paper's row (Table 4 order)
PAPER: dict[str, PaperRow] = {env_id: info.paper for env_id, info in ENV_INFO.items() if info.paper is not None}

#: the thirteen q-only benchmarks of Table 4 (``--envs all``)
TABLE4_ENVS: tuple[str, ...] = tuple(PAPER)

__all__ = ["PAPER", "PAPER_FULL_STATE", "TABLE4_ENVS", "PaperRow"]
