"""Linear algebra on shooting columns (residual directions flattened over windows and samples)."""

from __future__ import annotations

import numpy as np


def flat(a: np.ndarray) -> np.ndarray:
    """(W, L*n[, k]) -> (W*L*n[, k])."""
    return a.reshape(-1, a.shape[-1]) if a.ndim == 3 else a.reshape(-1)


def orth_against(cols: np.ndarray, basis: np.ndarray | None) -> np.ndarray:
    """Columns (N, k) minus their projection on span(basis (N, m))."""
    if basis is None or basis.shape[1] == 0:
        return cols
    Q = np.linalg.qr(basis)[0]
    return cols - Q @ (Q.T @ cols)


def rel_resid(col: np.ndarray, basis: np.ndarray | None) -> float:
    """|col - proj_basis(col)| / |col|: the share of ``col`` not explained by ``basis``."""
    n0 = float(np.linalg.norm(col))
    if n0 == 0:
        return 0.0
    return float(np.linalg.norm(orth_against(col[:, None], basis))) / n0


def cluster_cov(X: np.ndarray, r: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, int]:
    """Cluster-robust (CR1) covariance of least-squares coefficients of X with residual r, clusters g; and the cluster
    count."""
    XtXi = np.linalg.pinv(X.T @ X)
    n, p = X.shape
    G, inv = np.unique(g, return_inverse=True)
    Xr = X * r[:, None]
    # each cluster's score sum X_k^T r_k, one pass over the rows per column (not one pass per cluster)
    s = np.zeros((len(G), p))
    for j in range(p):
        s[:, j] = np.bincount(inv.ravel(), weights=Xr[:, j], minlength=len(G))
    meat = s.T @ s
    corr = len(G) / max(len(G) - 1, 1) * (n - 1) / max(n - p, 1)
    return corr * XtXi @ meat @ XtXi, len(G)
