"""``bracketry slam``: the SLAM backend's tools (ORB-SLAM3 vocabulary)."""

from __future__ import annotations

from pathlib import Path

import click

from bracketry.errors import BracketryError


@click.group("slam")
def command() -> None:
    """Tools of the benchmark's SLAM backend (ORB-SLAM3)."""


@command.command("vocabulary")
@click.argument("images", nargs=-1, type=click.Path(dir_okay=False))
@click.option("--out", "out_file", required=True, type=click.Path(dir_okay=False), help="Vocabulary text file.")
@click.option("--k", "k", default=10, show_default=True, type=click.IntRange(2, 20), help="Branching factor.")
@click.option("--levels", "-L", default=5, show_default=True, type=click.IntRange(1, 10),
              help="Depth (every branch padded to it).")
@click.option("--seed", default=0, show_default=True, type=int, help="Seed of the k-means++ draws.")
@click.option("--max-iter", default=10, show_default=True, type=click.IntRange(1, 100),
              help="k-means iterations per node at most.")
@click.option("--overwrite", is_flag=True, help="Replace an existing --out file.")
def vocabulary(images: tuple[str, ...], out_file: str, k: int, levels: int, seed: int, max_iter: int,
               overwrite: bool) -> int:
    """Train a DBoW2 vocabulary (ORB-SLAM's text format) on the ORB features of IMAGES.

    IMAGES: 8-bit images, or 16-bit RGGB mosaics of 12-bit codes (BorealHDR, emulated runs); each image counts as
    one document for the TF-IDF weights. Deterministic: the same images and --seed give the same file. Use images
    that are not the benchmark's. Without IMAGES, the benchmark's default vocabulary is built (synthetic training
    images) and cached in the user cache; --out then receives a copy.
    """
    from bracketry_emulator.slam.vocabulary_files import (
        descriptors_of_files,
        ensure_default_vocabulary,
        write_vocabulary,
    )

    out = Path(out_file)
    if out.exists() and not overwrite:
        raise BracketryError(f"{out} exists (pass --overwrite to replace it)")
    if not images:
        import shutil

        src = ensure_default_vocabulary(echo=click.echo)
        shutil.copyfile(src, out)
        click.echo(f"vocabulary: {out} (the default, cached at {src})")
        return 0
    missing = [p for p in images if not Path(p).is_file()]
    if missing:
        raise BracketryError(f"image not found: {missing[0]}" + (f" (and {len(missing) - 1} more)"
                                                                  if len(missing) > 1 else ""))
    descriptors = descriptors_of_files(images)
    n = sum(len(d) for d in descriptors)
    if n == 0:
        raise BracketryError("no ORB features in the given images")
    write_vocabulary(descriptors, out, k=k, levels=levels, seed=seed, max_iter=max_iter)
    click.echo(f"vocabulary: {out} (k={k}, L={levels}, {n} descriptors from {len(images)} images, seed {seed})")
    return 0
