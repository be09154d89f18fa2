"""``bracketry emulate``: emulate images at chosen exposures and run AE methods in closed loop on a dataset."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from bracketry_base.errors import BracketryError
from bracketry_base.options import (
    EXIT_OK,
    WORKERS,
    Number,
    count,
    input_path,
    method_options_options,
    output_dir,
    overwrite_option,
    quiet_option,
)
from bracketry_emulator.defaults import CAMERAS, FUSION_BRACKETS, PNG_COMPRESSIONS
from bracketry_emulator.option_table import EMULATE, options_for, pop_settings, record_values

if TYPE_CHECKING:
    from bracketry_emulator.emulation import EmulatorConfig


def _emulator_config(dataset: Path, selection: str, crf: str | None, parity: str, depth: int,
                     gain_db: float, noise: Path | None = None, fusion_brackets: str = FUSION_BRACKETS[0],
                     motion: str = "none", deghost_sigma: float | None = None) -> EmulatorConfig:
    from bracketry_emulator.emulation.noise import resolve_noise_model
    from bracketry_emulator.emulation.settings import emulator_config

    if crf is None:
        crf = "srgb"
        if parity == "upstream":  # the authors' arithmetic goes with their pcalib: take the dataset's
            from bracketry_emulator.dataset import open_dataset

            found = open_dataset(dataset).pcalib_path()
            if found is None:
                raise BracketryError("--parity upstream needs the authors' pcalib: pass --crf PATH/pcalib_inside1.txt")
            crf = str(found)
    fusion_options = fusion_brackets != FUSION_BRACKETS[0] or motion != "none" or deghost_sigma is not None
    if selection != "fusion" and fusion_options:
        raise BracketryError("--fusion-brackets, --motion and --deghost-sigma need --selection fusion")
    if deghost_sigma is not None and deghost_sigma <= 0:
        raise BracketryError(f"--deghost-sigma must be > 0, got {deghost_sigma}")
    model, _source = resolve_noise_model(noise, dataset if dataset.is_dir() else None)
    return emulator_config(selection, crf, parity, depth=depth, gain_db=gain_db, fusion_brackets=fusion_brackets,
                           motion=motion, deghost_sigma=deghost_sigma, noise=model)


@click.command("emulate")
@click.argument("dataset", type=input_path())
@click.option("--out", "-o", "out_dir", required=True, type=output_dir(),
              help="Output folder (new or empty): one sub-folder per method, summary.json, exposures.csv, "
                   "exposure_times.png.")
@options_for(EMULATE)
@method_options_options()
@click.option("--camera", type=click.Choice(CAMERAS), default=CAMERAS[-1], show_default=True,
              help="Cameras to emulate and write.")
@click.option("--depth", type=click.Choice(["12", "8"]), default="12", show_default=True,
              help="Bit depth of written images (12: 16-bit PNG of 12-bit codes; 8: code >> 4).")
@click.option("--gain-db", type=Number(0.0, 48.0), default=0.0, show_default=True,
              help="Emulated analog gain in dB, 0 to 48.")
@click.option("--noise", type=click.Path(path_type=Path, exists=True, dir_okay=False), default=None,
              help="Camera noise model for --gain-db and fusion weights: a calibrate crf --noise-out JSON or a "
                   "camera_model.json [default: DATASET/camera_model.json when present, else built-in].")
@click.option("--fusion-brackets", type=click.Choice(FUSION_BRACKETS), default=FUSION_BRACKETS[0], show_default=True,
              help="Fusion: the two brackets around the target and every longer one, the two only, or every bracket.")
@click.option("--motion", type=click.Choice(["none", "translation", "homography"]), default="none",
              show_default=True, help="Fusion: global motion compensation between the brackets.")
@click.option("--deghost-sigma", type=Number(0.0, 1e6, min_open=True), default=None,
              help="Fusion: drop pixels of a non-reference bracket more than this many noise sigmas off the reference.")
@click.option("--workers", "-j", type=WORKERS, default=0, show_default=True,
              help="Worker processes (0 = automatic: up to min(methods, CPUs, 4) from 8 sequences on, else this "
                   "process; 1 = in this process).")
@click.option("--max-sequences", type=count(1), default=None, help="Stop after this many bracket sequences.")
@click.option("--no-images", is_flag=True, help="Do not write images (exposure trajectories and summaries only).")
@click.option("--png-compression", type=click.Choice(PNG_COMPRESSIONS), default=PNG_COMPRESSIONS[0],
              show_default=True,
              help="Lossless PNG encoding of the images: stored (no compression, fastest, 2 bytes a pixel), fast "
                   "(Huffman only), small (zlib level 1, smallest), opencv (cv2.imwrite defaults, as the authors); "
                   "time and size of each: emulator/DATASET.md.")
@overwrite_option("Replace an earlier run in the same --out (its method folders and summaries are removed first).")
@quiet_option()
def command(dataset: Path, out_dir: Path, method_option: tuple[str, ...], method_options: Path | None, camera: str,
            depth: str, gain_db: float, noise: Path | None, fusion_brackets: str, motion: str,
            deghost_sigma: float | None, workers: int, max_sequences: int | None, no_images: bool,
            png_compression: str, overwrite: bool, quiet: bool, **given: Any) -> int:
    """Run AE methods in closed loop on DATASET (BorealHDR tree, synthetic world, a .zip of either, or MCAP).

    Every method starts at --init-exposure-ms; at each bracket sequence its current target is emulated for the
    cameras, the images are written, and the method picks the next target from the --ae-camera image. Each decoded
    bracket sequence is shared by all methods; methods run in parallel worker processes.
    """
    from bracketry_emulator.runtime_policy import apply_profile

    apply_profile("emulate")  # before numpy loads (just below); the forked workers inherit it
    from bracketry_emulator.ae import LoopConfig, parse_method_options, resolve_methods, run_methods

    settings = pop_settings(EMULATE, given)
    assert not given, f"options without a row in the settings table: {sorted(given)}"
    chosen = record_values(EMULATE, settings, "methods")
    drl_weights: str | None = chosen.get("drl_weights")
    values = record_values(EMULATE, settings, "loop")
    emu = _emulator_config(dataset, values.pop("emulator.selection"), values.pop("emulator.crf", None),
                           values["emulator.parity"], int(depth), gain_db, noise, fusion_brackets, motion,
                           deghost_sigma)
    cfg = LoopConfig.from_values({**values, "emulator.selection": emu.selection, "emulator.crf": str(emu.crf)},
                                 emulator=emu, camera=camera, write_images=not no_images,
                                 png_compression=png_compression, overwrite=overwrite, max_sequences=max_sequences)
    # the methods, resolved once (names checked, plugins created, before any work): what the workers get
    resolved = resolve_methods(chosen["methods"], parse_method_options(method_option, method_options),
                               drl_weights=drl_weights, seed=cfg.seed, parity=cfg.emulator.parity,
                               warn=lambda m: click.echo(m, err=True))
    if drl_weights is not None and any(m.source == "drl" for m in resolved):
        _check_pth(Path(drl_weights))
    if overwrite:
        remove_earlier_run(out_dir)
    summary = run_methods(dataset, resolved, out_dir, workers=workers, config=cfg, progress=not quiet)
    click.echo(f"{len(summary.runs)} method(s) x {summary.n_sequences} sequence(s), cameras "
               f"{','.join(summary.sides)}, in {summary.wall_s:.1f} s -> {summary.out_dir}")
    for name, run in summary.runs.items():
        s = run.summary()
        exp = s["exposure_ms"]
        click.echo(f"  {name:<12} exposure ms first {exp['first']:.3f} last {exp['last']:.3f} "
                   f"mean {exp['mean']:.3f}  AE {s['ae_ms_per_step']['median']:.1f} ms/step")
    for m in resolved:
        if not m.plain:
            click.echo(f"  plugin {m.describe()}")
    if summary.plot_path:
        click.echo(f"  plot: {summary.plot_path}")
    warn_dataset_problems(summary.problems)
    return EXIT_OK


def _check_pth(path: Path) -> None:
    """Refuse a --drl-weights file that is not a PyTorch file before any work, without importing torch here (the
    worker processes are forked from this one and load the actor themselves)."""
    import zipfile

    with open(path, "rb") as f:
        head = f.read(2)
    if not zipfile.is_zipfile(path) and not head.startswith(b"\x80"):
        raise BracketryError(f"DRL weights {path} are not a PyTorch .pth file (a zip or pickle of the actor's "
                             "state_dict)")


def remove_earlier_run(out_dir: Path) -> None:
    """``--overwrite``: remove what an earlier run wrote into ``out_dir`` (the method folders its summary.json
    lists, its summaries and plot), so the new summary never lists methods of two different runs."""
    import json
    import shutil

    from bracketry_emulator.ae.writers import method_folder

    summary = out_dir / "summary.json"
    if not summary.is_file():
        return
    try:
        methods = json.loads(summary.read_text()).get("methods", {})
    except (OSError, ValueError):
        methods = {}
    for spec in methods:
        folder = out_dir / method_folder(spec)
        if folder.is_dir() and folder.resolve().parent == out_dir.resolve():
            shutil.rmtree(folder)
    for name in ("summary.json", "exposures.csv", "exposure_times.png"):
        (out_dir / name).unlink(missing_ok=True)


def warn_dataset_problems(problems: list[str], shown: int = 5) -> None:
    """One stderr line per dataset problem (incomplete sequence, skipped file), at most ``shown`` of them."""
    for line in problems[:shown]:
        click.echo(f"warning: dataset: {line}", err=True)
    if len(problems) > shown:
        click.echo(f"warning: dataset: {len(problems) - shown} more problem(s), see dataset_problems in summary.json",
                   err=True)
