"""Quickstart: make an env, step it with random torques, save a rendered frame.

    python examples/quickstart.py --out quickstart.png
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import phast_gym  # noqa: E402,F401  (registers the PHAST/* ids)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--env", default="PHAST/WindyPendulum-v0")
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--out", default="quickstart.png")
    args = ap.parse_args()

    env = gym.make(args.env, render_mode="rgb_array")
    obs, info = env.reset(seed=0)  # obs = q only (angles wrapped); info["state"] = true (q, p)
    print(f"{args.env}: obs {obs}, true state {info['state']}, energy {info['energy']:.3f}")
    for _ in range(args.steps):
        action = env.action_space.sample()  # the port input: a torque / force / voltage
        obs, reward, terminated, truncated, info = env.step(action)
    print(f"after {args.steps} steps (t = {info['t']:.2f} s): obs {obs}, energy {info['energy']:.3f}, "
          f"damping {info['damping']}, reward {reward:.3f}")
    frame = env.render()  # (H, W, 3) uint8, pure numpy
    plt.imsave(args.out, frame)
    print(f"frame {frame.shape} written to {args.out}")
    env.close()


if __name__ == "__main__":
    main()
