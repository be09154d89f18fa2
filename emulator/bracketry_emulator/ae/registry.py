"""Method ids -> AE method objects, and the plugin loader.

Built-in ids: ``fix``, ``ae30``, ``ae50``, ``ae70``, ``shim``, ``wang``, ``kim``, ``zhang``, ``drl`` and
``constant-<ms>`` (e.g. ``constant-8``). A plugin is ``pkg.module:ClassName`` (any importable class or factory
returning an object with the :class:`AEMethod` protocol) or the name of an entry point in the group
``bracketry.ae_methods``. See PLUGINS.md.
"""

from __future__ import annotations

import functools
import importlib
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from bracketry.errors import BracketryError

from .base import AEMethod
from .classical import ClassicalAE, ConstantExposure, ConvergingFixAE, FixAE

if TYPE_CHECKING:
    from importlib.metadata import EntryPoint

#: The eight methods of the paper, in its table order.
PAPER_METHODS: tuple[str, ...] = ("fix", "ae30", "ae50", "ae70", "shim", "wang", "kim", "drl")
#: Every built-in id (``all`` on the command line is :data:`PAPER_METHODS`; ``zhang`` by name).
BUILTIN_METHODS: tuple[str, ...] = (*PAPER_METHODS, "zhang")
ENTRY_POINT_GROUP = "bracketry.ae_methods"
_CONSTANT = re.compile(r"^constant-(\d+(?:\.\d*)?|\.\d+)$")


#: The methods that have an authors' variant (``parity="upstream"``, :mod:`.upstream`); the others run the same
#: implementation in both modes (classical and Fix are the authors' rule already; Wang and DRL are not in their code).
UPSTREAM_VARIANTS: tuple[str, ...] = ("fix", "shim", "kim", "zhang")
PARITIES: tuple[str, ...] = ("default", "upstream")


def _builtin(name: str, options: dict[str, Any]) -> Callable[[], AEMethod] | None:
    """The factory of a built-in id (nothing created yet), or None."""
    seed = int(options.get("seed", 0))
    parity = options.get("parity", "default") or "default"
    if parity not in PARITIES:
        raise BracketryError(f"unknown AE mode {parity!r} (use default or upstream)")
    if parity == "upstream" and name in UPSTREAM_VARIANTS:
        from . import upstream

        if name == "fix":
            return FixAE
        if name == "shim":
            return upstream.UpstreamShimAE
        if name == "kim":
            return functools.partial(upstream.UpstreamKimAE, seed=seed)
        return upstream.UpstreamZhangAE
    if name in ("ae30", "ae50", "ae70"):
        return functools.partial(ClassicalAE, float(name[2:]), name=name, parity=parity)
    if name == "fix":
        return FixAE if parity == "upstream" else ConvergingFixAE
    if name == "shim":
        from .shim import ShimAE

        return ShimAE
    if name == "kim":
        from .kim import KimAE

        return functools.partial(KimAE, seed=seed)
    if name == "zhang":
        from .zhang import ZhangAE

        return ZhangAE
    if name == "wang":
        from .wang import WangAE

        return WangAE
    if name == "drl":
        from .drl import DrlAE

        return functools.partial(DrlAE, options.get("drl_weights"))
    m = _CONSTANT.match(name)
    if m:
        ms = float(m.group(1))
        if ms <= 0:
            raise BracketryError(f"constant exposure must be positive: {name}")
        return functools.partial(ConstantExposure, ms, name=name)
    return None


def _entry_points() -> dict[str, EntryPoint]:
    import importlib.metadata  # only for ids that are not built in (its import is ~0.05 s of every start-up)

    return {ep.name: ep for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)}


def _instantiate(factory: Any, spec: str, options: dict[str, Any]) -> AEMethod:
    if not callable(factory):
        raise BracketryError(f"AE plugin {spec} is not a class or factory")
    try:
        obj = factory(**options.get("plugin_kwargs", {}))
    except TypeError as exc:
        raise BracketryError(f"AE plugin {spec} cannot be created without arguments: {exc}") from exc
    for attr in ("reset", "next_exposure_us"):
        if not callable(getattr(obj, attr, None)):
            raise BracketryError(f"AE plugin {spec} has no method {attr}() (see the AEMethod protocol, PLUGINS.md)")
    if not isinstance(getattr(obj, "name", None), str) or not obj.name:
        try:
            obj.name = spec.split(":")[-1]
        except AttributeError as exc:
            raise BracketryError(f"AE plugin {spec} has no 'name' and it cannot be set") from exc
    return obj


def load_plugin(spec: str, options: dict[str, Any] | None = None) -> AEMethod:
    """A method from ``pkg.module:Attr`` (import path) -> instance of that class/factory (no arguments)."""
    options = options or {}
    module_name, _, attr = spec.partition(":")
    if not module_name or not attr:
        raise BracketryError(f"bad plugin spec {spec!r} (use pkg.module:ClassName)")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise BracketryError(f"cannot import AE plugin module {module_name}: {exc}") from exc
    factory: Any = module
    for part in attr.split("."):
        factory = getattr(factory, part, None)
        if factory is None:
            raise BracketryError(f"AE plugin module {module_name} has no {attr}")
    return _instantiate(factory, spec, options)


def get_method(spec: str, **options: Any) -> AEMethod:
    """The AE method of one id (see the module docstring); ``options``: ``seed`` (Kim's GP, default 0),
    ``drl_weights`` (path of the DRL actor), ``plugin_kwargs`` (keyword arguments for a plugin class), ``parity``
    ("default": each method as its paper describes it, corrections documented per method; "upstream": the authors'
    code step for step for shim, kim and zhang, see :mod:`.upstream`; plugins ignore it).

    Raises BracketryError (one line) for an unknown id or a plugin that cannot be loaded.
    """
    name = spec.strip()
    factory = _builtin(name.lower(), options)
    if factory is not None:
        return factory()
    if ":" in name:
        return load_plugin(name, options)
    eps = _entry_points()
    if name in eps:
        try:
            factory = eps[name].load()
        except Exception as exc:
            raise BracketryError(f"cannot load AE entry point {name} ({eps[name].value}): {exc}") from exc
        method = _instantiate(factory, eps[name].value, options)
        return method
    known = ", ".join([*BUILTIN_METHODS, "constant-<ms>", *sorted(eps)])
    raise BracketryError(f"unknown AE method {spec!r} (known: {known}; or a plugin pkg.module:Class)")


def expand_methods(specs: str | list[str], has_drl_weights: bool = True,
                   warn: Callable[[str], None] | None = None) -> list[str]:
    """Split a comma list, expand ``all`` (the paper's eight; drl only when weights are given), drop duplicates."""
    items = specs.split(",") if isinstance(specs, str) else list(specs)
    out: list[str] = []
    for raw in items:
        s = raw.strip()
        if not s:
            continue
        if s.lower() == "all":
            for b in PAPER_METHODS:
                if b == "drl" and not has_drl_weights:
                    if warn:
                        warn("note: 'all' skips drl (no --drl-weights given)")
                    continue
                if b not in out:
                    out.append(b)
        elif s not in out:
            out.append(s)
    if not out:
        raise BracketryError("no AE method given (e.g. --method ae50,shim or --method all)")
    return out


#: Relative cost of one step of a method that declares no ``step_cost`` (emulating and writing a step: ~20).
DEFAULT_STEP_COST = 10


@dataclass(frozen=True)
class MethodTraits:
    """What a method declares for the scheduler (optional attributes of the method or its class).

    Attributes:
        step_cost: relative cost of one step (``step_cost``; default :data:`DEFAULT_STEP_COST`), for balancing
            worker processes.
        step_group: methods with the same ``step_group`` take identical first steps (same images): kept on one
            worker, whose writer links those images instead of encoding them again (None: no group).
        start_up: a one-off start-up that methods naming the same ``start_up`` share within a worker process (e.g.
            ``"scipy"``: importing it, ~0.35 CPU-s here): kept on one worker where the balance allows (None: none).
    """

    step_cost: int = DEFAULT_STEP_COST
    step_group: str | None = None
    start_up: str | None = None


def method_traits(spec: str, **options: Any) -> MethodTraits:
    """Check the id ``spec`` as :func:`get_method` does and return what its method declares for scheduling.

    A method class with ``created_in_worker = True`` (creating it starts threads, e.g. torch's) is not created
    here: its ``check_options(**options)`` is called instead and its class attributes are read. Raises
    BracketryError (one line) as :func:`get_method`."""
    factory = _builtin(spec.strip().lower(), options)
    cls = factory.func if isinstance(factory, functools.partial) else factory
    source: Any
    if isinstance(cls, type) and getattr(cls, "created_in_worker", False):
        cls.check_options(**options)  # type: ignore[attr-defined]
        source = cls
    else:
        source = factory() if factory is not None else get_method(spec, **options)
    return MethodTraits(int(getattr(source, "step_cost", DEFAULT_STEP_COST)), getattr(source, "step_group", None),
                        getattr(source, "start_up", None))
