"""The optional-extension loader: every built extension found, looked up once, None where it is not built, with
``BRACKETRY_NO_CKERNEL=1`` or inside ``extensions_disabled()`` (nested, in every thread)."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from types import ModuleType

import pytest

from bracketry_emulator import extensions
from bracketry_emulator.extensions import clear_extension_cache, extensions_disabled, optional_extension

BUILT = ["bracketry_emulator.emulation._lut12", "bracketry_emulator.dataset._pngcodec",
         "bracketry_emulator.ae._zhang_terms", "bracketry_emulator.ae._upstream_kernels",
         "bracketry_emulator.synth._kernels"]


@pytest.fixture
def fresh_cache(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    monkeypatch.delenv("BRACKETRY_NO_CKERNEL", raising=False)
    clear_extension_cache()
    yield
    monkeypatch.delenv("BRACKETRY_NO_CKERNEL", raising=False)
    clear_extension_cache()


@pytest.mark.usefixtures("fresh_cache")
def test_every_extension_is_built_and_looked_up_once(monkeypatch: pytest.MonkeyPatch) -> None:
    modules = [optional_extension(name) for name in BUILT]
    assert all(isinstance(m, ModuleType) for m in modules), "an extension was not built (setup.sh builds them)"
    assert [m.__name__ for m in modules if m is not None] == BUILT
    monkeypatch.setenv("BRACKETRY_NO_CKERNEL", "1")  # read at the first look-up only
    assert [optional_extension(name) for name in BUILT] == modules
    assert optional_extension("bracketry_emulator.emulation._not_built") is None


@pytest.mark.usefixtures("fresh_cache")
def test_no_ckernel_env_and_clear_cache(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("BRACKETRY_NO_CKERNEL", "1")
    assert all(optional_extension(name) is None for name in BUILT)
    monkeypatch.setenv("BRACKETRY_NO_CKERNEL", "0")
    assert optional_extension(BUILT[0]) is None  # still the first look-up's answer
    clear_extension_cache()
    assert optional_extension(BUILT[0]) is not None


@pytest.mark.usefixtures("fresh_cache")
def test_extensions_disabled_nests_and_holds_in_other_threads() -> None:
    module = optional_extension(BUILT[0])
    assert module is not None
    seen: list[ModuleType | None] = []
    with extensions_disabled():
        with extensions_disabled():
            assert optional_extension(BUILT[0]) is None
        assert all(optional_extension(name) is None for name in BUILT)
        worker = threading.Thread(target=lambda: seen.append(optional_extension(BUILT[0])))
        worker.start()
        worker.join()
    assert seen == [None]
    assert optional_extension(BUILT[0]) is module
    with pytest.raises(RuntimeError), extensions_disabled():
        raise RuntimeError("left by an exception")
    assert optional_extension(BUILT[0]) is module and extensions._DISABLED == 0
