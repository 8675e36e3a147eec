"""What the fitting stages share: the prepared problem and the linear algebra on shooting columns.

* :mod:`.problem`: :func:`~.problem.prepare`, the training recordings, their noise and scales, the shooting windows
  and the nominal model family every stage fits in;
* :mod:`.linear`: shooting columns flattened over windows and samples, projections, cluster-robust covariances.

The multiple-shooting fit itself (windows, window states, Gauss-Newton with damping) is shared with the world model's
rig path and lives in :mod:`phast_model.identify.shooting`.
"""
