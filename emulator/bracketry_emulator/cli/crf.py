"""``bracketry calibrate-crf STACK_DIR --out pcalib.txt``: camera response (and noise model) from a static stack."""

from __future__ import annotations

import json
from pathlib import Path

import click
import numpy as np

from bracketry_base.errors import BracketryError
from bracketry_base.options import EXIT_OK, count, input_dir, output_file, overwrite_option


@click.command("calibrate-crf")
@click.argument("stack_dir", type=input_dir())
@click.option("--out", "out_path", type=output_file(), required=True,
              help="The pcalib file to write (its folder must exist).")
@overwrite_option()
@click.option("--levels", type=click.Choice(["4096", "256"]), default="4096", show_default=True,
              help="4096 values (every 12-bit code) or 256 (TUM-compatible, codes linspace(0, 4095, 256)).")
@click.option("--iterations", type=count(1, 1000), default=10, show_default=True,
              help="Alternating least-squares iterations.")
@click.option("--max-images", type=count(2, 100000), default=24, show_default=True,
              help="Frames used (evenly spread over the exposures).")
@click.option("--side", type=click.Choice(["left", "right"]), default="left", show_default=True,
              help="Camera side of a plain BorealHDR-tree stack.")
@click.option("--noise-out", type=output_file(suffixes=(".json",)), default=None,
              help="Also fit the noise model (read noise, DN per electron) from the repeats and write it as JSON.")
def command(stack_dir: Path, out_path: Path, overwrite: bool, levels: str, iterations: int, max_images: int,
            side: str, noise_out: Path | None) -> int:
    """Calibrate the inverse camera response f^-1 from a static exposure stack (TUM alternating least squares at
    4096 levels, saturated pixels masked) and write it as a pcalib file usable with --crf."""
    from bracketry_emulator.accuracy.stack import open_static_stack
    from bracketry_emulator.crf import SrgbResponse, TableResponse, pcalib256_from_icrf, save_pcalib
    from bracketry_emulator.crf.calibrate import calibrate_response
    from bracketry_emulator.dataset import read_png12
    from bracketry_emulator.emulation.noise import calibrate_noise

    if noise_out is not None and noise_out.resolve() == out_path.resolve():
        raise BracketryError("--noise-out and --out name the same file")
    stack = open_static_stack(stack_dir, side=side)
    if noise_out is not None and not stack.repeats:
        raise BracketryError("--noise-out needs repeated frames (repeats/ in the stack)")
    frames = [(round(s.exposure_us), s.path) for s in stack.sweep]
    frames += [(e, p) for e, p in stack.brackets.items()]
    frames.sort()
    if len(frames) > max_images:
        pick = np.unique(np.linspace(0, len(frames) - 1, max_images).round().astype(int))
        frames = [frames[i] for i in pick]
    pairs = [(e, read_png12(p)) for e, p in frames]
    cal = calibrate_response(pairs, iterations=iterations)
    values = cal.icrf if levels == "4096" else pcalib256_from_icrf(cal.icrf)
    save_pcalib(out_path, values)
    srgb = SrgbResponse()
    ref = srgb.icrf[srgb.used_codes]
    got = cal.icrf[srgb.used_codes]
    dev = float(np.median(np.abs(got - ref) / np.maximum(ref, 1.0)))
    click.echo(f"{len(pairs)} frames, {len(cal.exposures_us)} exposures "
               f"({cal.exposures_us[0] / 1000:g}..{cal.exposures_us[-1] / 1000:g} ms), {cal.n_pixels} pixels each; "
               f"residual {cal.residual_rms[-1]:.2f} DN after {iterations} iterations; "
               f"{int(cal.observed.sum())} codes observed")
    click.echo(f"median relative difference to the sRGB 12-bit model: {100 * dev:.1f} %")
    click.echo(f"wrote {out_path} ({values.size} values)")
    if noise_out is not None:
        repeats = stack.load_repeats()
        model = calibrate_noise({round(e): fr for e, fr in repeats.items()}, TableResponse(cal.icrf))
        noise_out.write_text(json.dumps({"read_dn": model.read_dn, "dn_per_e": model.dn_per_e}, indent=2) + "\n")
        click.echo(f"noise model: read {model.read_dn:.3f} DN, {model.dn_per_e:.4f} DN/e-; wrote {noise_out}")
    return EXIT_OK
