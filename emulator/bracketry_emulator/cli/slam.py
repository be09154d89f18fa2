"""``bracketry slam``: the SLAM backend's tools (ORB-SLAM3 vocabulary)."""

from __future__ import annotations

from pathlib import Path

import click

from bracketry_base.errors import BracketryError
from bracketry_base.options import EXIT_OK, SEED, Integer, input_file, output_file, overwrite_option


@click.group("slam")
def command() -> None:
    """Tools of the benchmark's SLAM backend (ORB-SLAM3)."""


@command.command("vocabulary")
@click.argument("images", nargs=-1, type=input_file())
@click.option("--out", "out_file", required=True, type=output_file(), help="Vocabulary text file to write.")
@overwrite_option("Replace an existing --out file.")
@click.option("--k", "k", default=10, show_default=True, type=Integer(2, 20), help="Branching factor.")
@click.option("--levels", "-L", default=5, show_default=True, type=Integer(1, 10),
              help="Depth (every branch padded to it).")
@click.option("--seed", default=0, show_default=True, type=SEED, help="Seed of the k-means++ draws.")
@click.option("--max-iter", default=10, show_default=True, type=Integer(1, 100),
              help="k-means iterations per node at most.")
def vocabulary(images: tuple[Path, ...], out_file: Path, overwrite: bool, k: int, levels: int, seed: int,
               max_iter: int) -> int:
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

    out = out_file
    if not images:
        import shutil

        src = ensure_default_vocabulary(echo=click.echo)
        shutil.copyfile(src, out)
        click.echo(f"vocabulary: {out} (the default, cached at {src})")
        return EXIT_OK
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
    return EXIT_OK
