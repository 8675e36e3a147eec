"""The policy observation of the loop's agent and of the SAC benchmark's agents (``benchmarks/sac``):
(sin q, cos q) of the last measurements (:func:`stack_frames`), built by one :class:`ObsBuilder` per episode stream,
the same in the world-model env (:mod:`.world_env`), the deployed controller (:mod:`.hold`) and the benchmark's
training and plant evaluation.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence

import numpy as np

#: length scale (m) of a Euclidean coordinate in the observation: ``tanh(x / EUCLID_SCALE)``
EUCLID_SCALE = 2.0


def stack_frames(buf: Sequence[np.ndarray], angle_dims: Sequence[int] | None = None) -> np.ndarray:
    """(sin q, cos q) of the buffered measurements, oldest first.  With ``angle_dims`` given, a coordinate not in it
    (a cart's position x) is observed as ``(tanh(x / EUCLID_SCALE), 0)`` instead: bounded, odd like sin q (the
    mirror symmetry's sign), and not aliased every 2 pi m."""
    rows = [np.asarray(b, dtype=np.float64).reshape(-1) for b in buf]
    s, c = np.sin(rows), np.cos(rows)
    if angle_dims is not None:
        eu = [i for i in range(s.shape[1]) if i not in set(angle_dims)]
        if eu:
            x = np.asarray(rows)[:, eu]
            s[:, eu], c[:, eu] = np.tanh(x / EUCLID_SCALE), 0.0
    return np.concatenate([s.reshape(-1), c.reshape(-1)]).astype(np.float32)


#: policy observations: ``frames`` (the default, q-only): (sin q, cos q) of the last ``frames`` noisy measurements;
#: ``frames+qdot``: that plus the true velocity (oracle-velocity ablation); ``state``: (sin q, cos q, qdot) of the true,
#: noise-free state (Gymnasium Pendulum-v1's observation, measured from our q; ablation).
OBS_MODES = ("frames", "frames+qdot", "state")


class ObsBuilder:
    """The policy observation of :data:`OBS_MODES` from the noisy measurement and the true state; one instance per
    episode stream, used by training and by the evaluation on the plant alike (the benchmark's ``FrameObs`` and
    ``evaluate_policy_on_plant``, the loop's world env and deployed controller)."""

    def __init__(self, frames: int = 3, mode: str = "frames", inertia: float = 1.0,
                 angle_dims: Sequence[int] | None = None) -> None:
        if mode not in OBS_MODES:
            raise ValueError(f"obs must be one of {OBS_MODES}, got {mode!r}")
        self.frames, self.mode, self.inertia = frames, mode, inertia
        self.angle_dims = None if angle_dims is None else tuple(int(i) for i in angle_dims)  # None: every q an angle
        self._buf: deque[np.ndarray] = deque(maxlen=frames)

    @property
    def size(self) -> int:
        return {"frames": 2 * self.frames, "frames+qdot": 2 * self.frames + 1, "state": 3}[self.mode]

    def reset(self, meas: np.ndarray, state: np.ndarray | None = None) -> np.ndarray:
        """Clear the buffer and fill it with ``frames`` copies of the first measurement."""
        self._buf.clear()
        self._buf.extend([np.asarray(meas, dtype=np.float64)] * self.frames)
        return self._obs(state)

    def push(self, meas: np.ndarray, state: np.ndarray | None = None) -> np.ndarray:
        self._buf.append(np.asarray(meas, dtype=np.float64))
        return self._obs(state)

    def _obs(self, state: np.ndarray | None) -> np.ndarray:
        if self.mode == "frames":
            return stack_frames(self._buf, self.angle_dims)
        if state is None:
            raise ValueError(f"obs {self.mode!r} needs the true state (info['state'])")
        q, p = float(state[0]), float(state[1])
        qdot = p / self.inertia  # the pendulum's velocity (p = I qdot)
        if self.mode == "state":
            return np.array([math.sin(q), math.cos(q), qdot], dtype=np.float32)
        return np.concatenate([stack_frames(self._buf), np.array([qdot], dtype=np.float32)])
