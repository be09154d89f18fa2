"""ExposureEnv and DRL training throughput on this machine: environment steps per second (each reward, each
observation) and SAC training steps per second (env step + one gradient step), CPU time and wall time.

Usage: .venv/bin/python benchmarks/bench_env.py [DATASET ...] [--steps 200] [--train-steps 150] [--repeats 3]
       [--batch-size 64]

DATASET: dataset folders, .mcap files or manifests (their train split); default: a constructed 256x160 scene
(``bracketry_emulator.envs.constructed_trajectory``). Environment steps are timed with random actions after the
trajectory is loaded (loading is timed apart, once); training after ``learning_starts`` random steps (each timed step
= one environment step + one gradient step at ``--batch-size``). One torch thread, one BLAS thread. Prints medians of
``--repeats`` runs, in steps per CPU second (what the machine can do) and per wall second (what it did under the
load of the moment: quote the load average printed).
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import time

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):  # before numpy and torch load
    os.environ[_var] = "1"


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("datasets", nargs="*")
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--train-steps", type=int, default=150)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--batch-size", type=int, default=64)
    args = ap.parse_args()

    import numpy as np
    import torch

    from bracketry_emulator.envs import ExposureEnv, constructed_trajectory, resolve_trajectories
    from bracketry_emulator.envs.train import TrainConfig, new_model, uint8_frames

    torch.set_num_threads(1)
    sources = resolve_trajectories(args.datasets, "train") if args.datasets else [constructed_trajectory(seed=0)]
    print(f"load average {os.getloadavg()[0]:.2f}; {len(sources)} trajectories")
    for obs_kind, reward in (("frames", "feat"), ("frames", "stat"), ("stats", "stat")):
        env = ExposureEnv(sources, reward=reward, observation=obs_kind, episode_steps=None)
        c0, w0 = _cpu(), time.perf_counter()
        env.reset(seed=0)
        load_cpu, load_wall = _cpu() - c0, time.perf_counter() - w0
        env.action_space.seed(0)
        cpu_rates, wall_rates = [], []
        for rep in range(args.repeats):
            env.reset(seed=rep)
            c0, w0 = _cpu(), time.perf_counter()
            for _ in range(args.steps):
                _, _, term, trunc, _ = env.step(env.action_space.sample())
                if term or trunc:
                    env.reset()
            cpu_rates.append(args.steps / max(_cpu() - c0, 1e-9))
            wall_rates.append(args.steps / (time.perf_counter() - w0))
        print(f"env {obs_kind:6s} reward {reward}: {statistics.median(cpu_rates):8.1f} steps/CPU-s "
              f"{statistics.median(wall_rates):8.1f} steps/s wall (median of {args.repeats} x {args.steps}); "
              f"first reset (loads) {load_cpu:.2f} CPU-s {load_wall:.2f} s")

    from stable_baselines3.common.vec_env import DummyVecEnv

    cfg = TrainConfig(batch_size=args.batch_size, buffer_size=max(1000, args.train_steps + 200),
                      learning_starts=100, reward="feat", episode_steps=None)
    venv = DummyVecEnv([lambda: uint8_frames(ExposureEnv(sources, reward="feat"))])
    venv.seed(0)
    model = new_model(venv, cfg)
    model.learn(cfg.learning_starts + 1)
    cpu_rates, wall_rates = [], []
    for _ in range(args.repeats):
        c0, w0 = _cpu(), time.perf_counter()
        model.learn(args.train_steps, reset_num_timesteps=False)
        cpu_rates.append(args.train_steps / max(_cpu() - c0, 1e-9))
        wall_rates.append(args.train_steps / (time.perf_counter() - w0))
    print(f"train SAC batch {args.batch_size}: {statistics.median(cpu_rates):6.2f} steps/CPU-s "
          f"{statistics.median(wall_rates):6.2f} steps/s wall (median of {args.repeats} x {args.train_steps}; "
          f"one env step + one gradient step each); rates {[round(r, 2) for r in cpu_rates]}")
    del np


if __name__ == "__main__":
    main()
