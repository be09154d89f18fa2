"""Vocabulary files: train from image files, the project's default vocabulary (built once, cached), the choice.

Which vocabulary a run uses (:func:`resolve_vocabulary`): the file the user names (``--vocabulary FILE``), else the
``PYORBSLAM3_VOCAB`` file (e.g. ORB-SLAM's own ``ORBvoc.txt``), else the project's default vocabulary. Nothing is
ever downloaded.

The default vocabulary is trained once on images that are not any benchmark's: the synthetic worlds of both presets
with seeds no command uses by default (:data:`DEFAULT_TRAINING`), left camera at 8 ms, every 3 s along the walk,
at 960x600, ORB features at the paper's settings, k = 10, L = 4, seed 0. It is written to the user cache
(``$XDG_CACHE_HOME/bracketry`` or ``~/.cache/bracketry``) under a name that carries a hash of the recipe and of the
synthetic world's code (:func:`~bracketry_emulator.synth.suite.code_digest`: the training images are that code's
renders), so a changed recipe or world builds a new file, two machines with the same code train the same words,
and a finished file is never rebuilt.

Why L = 4 (10^4 words): ORB-SLAM groups a frame's features by the vocabulary node 4 levels above the leaves and
matches two frames' features only within a group. At L = 4 that node is the root: every feature pair is compared
(ORB-SLAM's ratio test and distance threshold decide), and the file (1.4 MB) loads in about 0.1 s, against 12.8 MB
and about 1 s at L = 5, once per SLAM run. Place recognition (relocalisation, loops) scores the 10^4 words.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from bracketry_base.errors import BracketryError
from bracketry_base.paths import user_cache_dir
from bracketry_emulator.slam.vocabulary import build_vocabulary, vocabulary_text

#: the default vocabulary's recipe (part of its file name through a hash)
DEFAULT_TRAINING: dict = {"presets": ["forest-winter", "campus-summer"], "world_seed": 9001, "resolution": [960, 600],
                          "times_s": [3.0 * i for i in range(1, 41)], "exposure_us": 8000.0, "k": 10, "levels": 4,
                          "seed": 0, "max_iter": 10, "format": 1}


def image_descriptors(gray8: np.ndarray) -> np.ndarray:
    """uint8 (n, 32) ORB descriptors of an 8-bit gray image (our extractor at the paper's settings)."""
    from bracketry_emulator.features.orb import OrbExtractor

    return OrbExtractor().detect_and_compute(gray8).descriptors


def descriptors_of_files(paths: Sequence[str | Path], bayer: bool | None = None) -> list[np.ndarray]:
    """ORB descriptors of image files (8-bit gray/colour, or 16-bit RGGB mosaics of 12-bit codes)."""
    import cv2

    from bracketry_emulator.features.demosaic import to_gray8

    out = []
    for p in paths:
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise BracketryError(f"cannot read image {p}")
        if img.ndim == 3:
            img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        gray = to_gray8(img, bayer=(img.dtype == np.uint16) if bayer is None else bayer)
        out.append(image_descriptors(gray))
    return out


def write_vocabulary(descriptors: list[np.ndarray], out: str | Path, k: int, levels: int, seed: int,
                     max_iter: int = 10) -> Path:
    """Train and write atomically (temporary file + rename)."""
    vocab = build_vocabulary(descriptors, k=k, levels=levels, seed=seed, max_iter=max_iter)
    path = Path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(vocabulary_text(vocab))
    os.replace(tmp, path)
    return path


def recipe_hash(recipe: dict) -> str:
    return hashlib.sha256(json.dumps(recipe, sort_keys=True).encode()).hexdigest()[:12]


def default_vocabulary_path(recipe: dict | None = None) -> Path:
    """Where the vocabulary of ``recipe`` (default :data:`DEFAULT_TRAINING`) trained on this code's renders lives."""
    from bracketry_emulator.synth.suite import code_digest

    r = recipe or DEFAULT_TRAINING
    key = recipe_hash({**r, "synth_code": code_digest()})
    return user_cache_dir() / "orbslam3" / f"vocabulary-k{r['k']}L{r['levels']}-{key}.txt"


def training_descriptors(recipe: dict) -> list[np.ndarray]:
    """Descriptors of the synthetic training images of ``recipe`` (see :data:`DEFAULT_TRAINING`)."""
    from bracketry_emulator.features.demosaic import to_gray8
    from bracketry_emulator.synth import World

    out = []
    for preset in recipe["presets"]:
        world = World(preset, seed=recipe["world_seed"], resolution=tuple(recipe["resolution"]))
        for t in recipe["times_s"]:
            raw = world.render("left", t_s=float(t), exposure_us=float(recipe["exposure_us"]))
            out.append(image_descriptors(to_gray8(raw, bayer=True)))
    return out


def ensure_default_vocabulary(recipe: dict | None = None, echo: Callable[[str], None] | None = None) -> Path:
    """The default vocabulary's path, training and caching it first if it is not there yet (minutes, once)."""
    r = recipe or DEFAULT_TRAINING
    path = default_vocabulary_path(r)
    if path.is_file():
        return path
    if echo:
        echo(f"building the ORB-SLAM3 vocabulary once (k={r['k']}, L={r['levels']}, synthetic training images): "
             f"{path}")
    lock = path.with_suffix(".lock")
    path.parent.mkdir(parents=True, exist_ok=True)
    import fcntl

    with open(lock, "w") as fh:  # concurrent benchmarks build it once
        fcntl.flock(fh, fcntl.LOCK_EX)
        if not path.is_file():
            write_vocabulary(training_descriptors(r), path, r["k"], r["levels"], r["seed"], r["max_iter"])
    return path


def resolve_vocabulary(explicit: str | Path | None, echo: Callable[[str], None] | None = None) -> Path:
    """The vocabulary a run uses: ``explicit``, else ``$PYORBSLAM3_VOCAB``, else the cached default (built once)."""
    for candidate, what in ((explicit, "--vocabulary"), (os.environ.get("PYORBSLAM3_VOCAB"), "PYORBSLAM3_VOCAB")):
        if candidate:
            p = Path(candidate).expanduser()
            if not p.is_file():
                raise BracketryError(f"{what}: vocabulary file not found: {p}")
            return p.resolve()
    return ensure_default_vocabulary(echo=echo)
