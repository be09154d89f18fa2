"""``bracketry train``: train learned AE methods on the emulator (``train drl``: the DRL actor, SAC on CPU)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from bracketry_base.errors import BracketryError
from bracketry_base.options import EXIT_OK, SEED, count, input_path, output_file, overwrite_option, quiet_option


@click.group("train")
def command() -> None:
    """Train learned AE methods on emulated exposures (needs the learn extra)."""


@command.command("drl")
@click.argument("datasets", nargs=-1, required=True, type=input_path())
@click.option("--steps", type=count(1, 100_000_000), required=True,
              help="Environment steps in all (a resumed run counts the checkpoint's steps).")
@click.option("--out", "out", type=output_file(existing="replace", suffixes=(".pth",)), required=True,
              help="The actor's weights (.pth, a state_dict that --drl-weights loads); checkpoints go to "
                   "<out>.ckpt/.")
@overwrite_option()
@click.option("--resume", is_flag=True, help="Continue from <out>.ckpt/ (learner and replay buffer).")
@click.option("--split", type=click.Choice(["train", "test", "all"]), default="train", show_default=True,
              help="The manifests' entries trained on (dataset folders are always used).")
@click.option("--reward", type=click.Choice(["feat", "stat"]), default="feat", show_default=True,
              help="The DRL paper's feature (ORB + matches) or statistics (mean, flicker) reward.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of the learner and the environments.")
@click.option("--envs", "n_envs", type=count(1, 64), default=1, show_default=True,
              help="Environments stepped together (the trajectories dealt among them).")
@click.option("--episode-steps", type=count(1, 1_000_000), default=200, show_default=True,
              help="Steps of an episode (a window of a trajectory at a random start).")
@click.option("--batch-size", type=count(1, 4096), default=64, show_default=True, help="SAC minibatch.")
@click.option("--buffer-size", type=count(100, 10_000_000), default=10_000, show_default=True,
              help="Replay buffer transitions (each ~57 kB).")
@click.option("--learning-starts", type=count(0, 10_000_000), default=1_000, show_default=True,
              help="Random-action steps before the first update.")
@click.option("--checkpoint-every", type=count(0, 100_000_000), default=5_000, show_default=True,
              help="Steps between checkpoints (0: only at the end).")
@click.option("--no-augment", is_flag=True, help="No time reversal or flips of episodes.")
@quiet_option()
def drl(datasets: tuple[Path, ...], steps: int, out: Path, overwrite: bool, resume: bool, split: str, reward: str,
        seed: int, n_envs: int, episode_steps: int, batch_size: int, buffer_size: int, learning_starts: int,
        checkpoint_every: int, no_augment: bool, quiet: bool) -> None:
    """Train the DRL actor from scratch (SAC, CPU) on DATASETS (dataset folders, .mcap files, manifests: their
    --split entries) and write its weights to --out."""
    from bracketry_emulator.envs.train import TrainConfig, checkpoint_dir, train_drl

    if resume and not (checkpoint_dir(out) / "model.zip").is_file():
        raise BracketryError(f"--resume: no checkpoint {checkpoint_dir(out)}/model.zip")
    if not resume and not overwrite:  # --resume rewrites the weights it goes on from
        for existing in (out, checkpoint_dir(out)):
            if existing.exists():
                raise BracketryError(f"--out {existing} exists (add --resume to continue it or --overwrite)")
    cfg = TrainConfig(steps=steps, seed=seed, reward=reward, n_envs=n_envs, episode_steps=episode_steps,
                      batch_size=batch_size, buffer_size=buffer_size, learning_starts=learning_starts,
                      augment=not no_augment, checkpoint_every=checkpoint_every, split=split)
    res = train_drl(list(datasets), out, cfg, resume=resume, quiet=quiet)
    last = [r for _, r in res.curve[-10:]]
    tail = f", mean return of the last {len(last)} episodes {sum(last) / len(last):.2f}" if last else ""
    click.echo(f"trained {res.new_steps} steps ({res.steps} in all) in {res.wall_s:.1f} s "
               f"({res.steps_per_s:.1f} steps/s){tail}")
    click.echo(f"weights: {res.weights} (run them: --methods drl --drl-weights {res.weights})")
    (res.checkpoint / "curve.json").write_text(json.dumps(res.curve))
    raise SystemExit(EXIT_OK)
