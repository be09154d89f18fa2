"""AE plugins as a researcher ships them, for the end-to-end tests of every command that takes methods.

- :func:`import_path_plugin`: a module in a folder (put it on PYTHONPATH), run as ``ae_kit_mod:Brighter``;
- :func:`entry_point_plugin`: a tiny package registering ``ae-kit-ep`` in the group ``bracketry.ae_methods``,
  installed with ``pip install --no-deps --no-build-isolation --target DIR`` (no network; its dist-info's
  entry_points.txt is what the registry finds on PYTHONPATH).
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

PLUGIN_MODULE = textwrap.dedent('''
    import numpy as np


    class Brighter:
        """Steer the mean code to ``target`` of full scale (default 0.45), half the error in stops per step."""

        name = "brighter"

        def __init__(self, target=0.45):
            self.target = float(target)

        def reset(self, init_exposure_us):
            pass

        def next_exposure_us(self, image, exposure_us, meta):
            mean = max(float(image[::4, ::4].mean()), 1.0)
            return exposure_us * (self.target * 4095 / mean) ** 0.5
''')


def import_path_plugin(root: Path) -> tuple[Path, str]:
    """(folder to put on PYTHONPATH, the id to pass to --methods); the method is named ``brighter``."""
    root.mkdir(parents=True, exist_ok=True)
    (root / "ae_kit_mod.py").write_text(PLUGIN_MODULE)
    return root, "ae_kit_mod:Brighter"


def entry_point_plugin(root: Path) -> tuple[Path, str]:
    """(folder to put on PYTHONPATH, the id to pass to --methods): the package ``ae_kit_ep`` built in ``root/src``
    and installed into ``root/site``; its entry point ``ae-kit-ep`` names the method ``darker`` (a subclass of the
    import-path one with another class name and target)."""
    src = root / "src"
    (src / "ae_kit_ep").mkdir(parents=True, exist_ok=True)
    (src / "ae_kit_ep" / "__init__.py").write_text(PLUGIN_MODULE + textwrap.dedent('''

        class Darker(Brighter):
            name = "darker"

            def __init__(self, target=0.25):
                super().__init__(target)
    '''))
    (src / "pyproject.toml").write_text(textwrap.dedent('''
        [build-system]
        requires = ["setuptools"]
        build-backend = "setuptools.build_meta"

        [project]
        name = "ae-kit-ep"
        version = "0.1"

        [project.entry-points."bracketry.ae_methods"]
        ae-kit-ep = "ae_kit_ep:Darker"

        [tool.setuptools]
        packages = ["ae_kit_ep"]
    '''))
    site = root / "site"
    res = subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation",
                          "--no-index", "--target", str(site), str(src)], capture_output=True, text=True,
                         timeout=300, env={**os.environ, "PIP_DISABLE_PIP_VERSION_CHECK": "1"})
    assert res.returncode == 0, res.stderr[-2000:]
    assert (site / "ae_kit_ep-0.1.dist-info" / "entry_points.txt").is_file(), sorted(p.name for p in site.iterdir())
    return site, "ae-kit-ep"


def env_with(*paths: Path) -> dict[str, str]:
    """The environment with ``paths`` first on PYTHONPATH."""
    old = os.environ.get("PYTHONPATH")
    return {**os.environ, "PYTHONPATH": os.pathsep.join([*map(str, paths), *([old] if old else [])])}


def bracketry(args: list[str], env: dict[str, str], cwd: Path | None = None,
              timeout: float = 900) -> subprocess.CompletedProcess[str]:
    """``python -m bracketry ARGS`` in a child process."""
    return subprocess.run([sys.executable, "-m", "bracketry", *args], capture_output=True, text=True, env=env,
                          cwd=cwd, timeout=timeout)
