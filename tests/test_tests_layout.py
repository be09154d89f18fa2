"""The tests folder mirrors the code (tests/README.md): every test file sits in a folder that exists in the code.

``tests/<package>/<x>/`` mirrors ``host/<package>/<x>/`` for ``bracketry_base``, ``bracketry_rig`` and
``bracketry``, ``tests/bracketry_emulator/<x>/`` mirrors
``emulator/bracketry_emulator/<x>/``, ``tests/firmware/<x>/`` mirrors ``firmware/<x>/``, ``tests/hw/`` mirrors ``hw/``;
``tests/demo/`` holds the end-to-end runs. Python files under tests/ have unique names, because pytest's default
"prepend" import mode (no ``__init__.py`` anywhere under tests/) imports test files and their helpers by file name.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

from bracketry_base.paths import repo_root

TESTS = Path(__file__).resolve().parent
#: first folder under tests/ -> the code folder it mirrors (None: a folder of its own, no code counterpart)
MIRRORS: dict[str, Path | None] = {
    "bracketry_base": repo_root() / "host" / "bracketry_base",
    "bracketry_rig": repo_root() / "host" / "bracketry_rig",
    "bracketry": repo_root() / "host" / "bracketry",
    "bracketry_emulator": repo_root() / "emulator" / "bracketry_emulator",
    "firmware": repo_root() / "firmware",
    "hw": repo_root() / "hw",
    "demo": None,
}
#: the only test files allowed at the top of tests/: checks of the whole tree (this one, the layers)
TOP_LEVEL_TESTS = {"test_tests_layout.py", "test_layers.py", "test_docs_commands.py", "test_docs_wording.py"}


def _python_files() -> list[Path]:
    return sorted(p for p in TESTS.rglob("*.py") if "__pycache__" not in p.parts and "node_modules" not in p.parts)


def _test_files() -> list[Path]:
    return [p for p in _python_files() if p.name.startswith("test_") or p.name.endswith("_test.py")]


def mirror_problems(tests_dir: Path, mirrors: dict[str, Path | None], test_files: list[Path]) -> list[str]:
    """One line per test file whose folder has no counterpart in the code."""
    problems = []
    for f in test_files:
        rel = f.relative_to(tests_dir)
        if len(rel.parts) == 1:
            if rel.name not in TOP_LEVEL_TESTS:
                problems.append(f"{rel}: a test file at the top of tests/ (put it in the folder of the code it tests)")
            continue
        top, *sub = rel.parts[:-1]
        if top not in mirrors:
            problems.append(f"{rel}: tests/{top}/ mirrors no code folder (one of {sorted(mirrors)})")
            continue
        code = mirrors[top]
        if code is None:
            if sub:
                problems.append(f"{rel}: tests/{top}/ has no sub-folders")
            continue
        # data folders of a test folder (e.g. ae/data/...) hold no test files, so every part must exist in the code
        if not code.joinpath(*sub).is_dir():
            problems.append(f"{rel}: {code.joinpath(*sub).relative_to(repo_root())}/ does not exist")
    return problems


def test_every_test_file_mirrors_a_code_folder() -> None:
    files = _test_files()
    assert len(files) > 50
    assert mirror_problems(TESTS, MIRRORS, files) == []


def test_mirror_check_fails_on_a_misplaced_test(tmp_path: Path) -> None:
    bad = [tmp_path / "wire" / "test_x.py", tmp_path / "bracketry_rig" / "nosuchpackage" / "test_y.py",
           tmp_path / "test_z.py", tmp_path / "demo" / "deeper" / "test_w.py"]
    good = [tmp_path / "bracketry_rig" / "wire" / "test_ok.py", tmp_path / "bracketry" / "test_ok2.py",
            tmp_path / "firmware" / "stm32_trigger" / "test_ok3.py", tmp_path / "demo" / "test_ok4.py"]
    mirrors = {**MIRRORS}
    problems = mirror_problems(tmp_path, mirrors, bad + good)
    assert len(problems) == len(bad)
    assert [p.split(":")[0] for p in problems] == [str(p.relative_to(tmp_path)) for p in bad]


def test_python_file_names_are_unique() -> None:
    """pytest's prepend import mode imports every test file and helper by its file name: two equal names collide."""
    names = Counter(p.name for p in _python_files() if p.name != "__init__.py")
    assert [n for n, c in names.items() if c > 1] == []
    assert [p.relative_to(TESTS) for p in TESTS.rglob("__init__.py")] == []
