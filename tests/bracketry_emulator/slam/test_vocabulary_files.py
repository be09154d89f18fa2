"""The default vocabulary's file name: one per recipe and per synthetic-world code (its training images are renders)."""

from __future__ import annotations

import pytest

from bracketry_emulator.slam import vocabulary_files
from bracketry_emulator.slam.vocabulary_files import DEFAULT_TRAINING, default_vocabulary_path
from bracketry_emulator.synth import suite


def test_the_name_follows_the_recipe_and_the_world_code(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    monkeypatch.setenv("BRACKETRY_CACHE", str(tmp_path))
    here = default_vocabulary_path()
    assert here == default_vocabulary_path(dict(DEFAULT_TRAINING))  # the same recipe and code: the same file
    assert here.name.startswith(f"vocabulary-k{DEFAULT_TRAINING['k']}L{DEFAULT_TRAINING['levels']}-")
    assert default_vocabulary_path({**DEFAULT_TRAINING, "seed": 1}) != here
    monkeypatch.setattr(suite, "code_digest", lambda: "0" * 12)  # another world renders other training images
    other = default_vocabulary_path()
    assert other != here and other.parent == here.parent
    assert vocabulary_files.recipe_hash(DEFAULT_TRAINING) not in other.name
