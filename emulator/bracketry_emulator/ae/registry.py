"""Method ids -> AE method objects, and the plugin loader.

Built-in ids: ``fix``, ``ae30``, ``ae50``, ``ae70``, ``shim``, ``wang``, ``kim``, ``zhang``, ``drl``,
``constant-<ms>`` (e.g. ``constant-8``) and the non-causal control ``oracle`` (:mod:`.oracle`). A plugin is
``pkg.module:ClassName`` (any importable class or factory returning an object with the :class:`AEMethod` protocol)
or the name of an entry point in the group ``bracketry.ae_methods``. See PLUGINS.md.

One name per method: :func:`resolve_methods` turns the ids given (and their options) into :class:`MethodSpec`s whose
``name`` (a built-in's id; a plugin's ``name`` attribute) names the output folders, CSV rows, statistics and plots,
refusing unsafe or colliding names before any work. While :func:`methods_in_use` holds them, :func:`get_method` and
:func:`method_traits` accept those names (also in forked worker processes).
"""

from __future__ import annotations

import contextlib
import functools
import importlib
import math
import re
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bracketry.errors import BracketryError

from ..stats.controls import CONTROLS_KEYWORD, NON_CAUSAL_METHODS, control_methods
from .base import AEMethod
from .classical import ClassicalAE, ConstantExposure, ConvergingFixAE, FixAE

if TYPE_CHECKING:
    from importlib.metadata import EntryPoint

#: The eight methods of the paper, in its table order.
PAPER_METHODS: tuple[str, ...] = ("fix", "ae30", "ae50", "ae70", "shim", "wang", "kim", "drl")
#: Every built-in id (``all`` on the command line is :data:`PAPER_METHODS`; ``zhang`` and ``oracle`` by name).
BUILTIN_METHODS: tuple[str, ...] = (*PAPER_METHODS, "zhang", "oracle")
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
    if name == "oracle":
        from .oracle import OracleAE

        return OracleAE
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
    kwargs = dict(options.get("plugin_kwargs") or {})
    try:
        obj = factory(**kwargs)
    except TypeError as exc:
        given = f"with options {_options_text(kwargs)}" if kwargs else "without arguments"
        raise BracketryError(f"AE plugin {spec} cannot be created {given}: {_one_line(exc)}") from exc
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
    if ":" not in spec:
        raise BracketryError(f"bad plugin spec {spec!r} (use pkg.module:ClassName)")
    factory, _name = _load_factory(spec)
    return _instantiate(factory, spec, options or {})


def get_method(spec: str, **options: Any) -> AEMethod:
    """The AE method of one id (see the module docstring); ``options``: ``seed`` (Kim's GP, default 0),
    ``drl_weights`` (path of the DRL actor), ``plugin_kwargs`` (keyword arguments for a plugin class), ``parity``
    ("default": each method as its paper describes it, corrections documented per method; "upstream": the authors'
    code step for step for shim, kim and zhang, see :mod:`.upstream`; plugins ignore it).

    Raises BracketryError (one line) for an unknown id or a plugin that cannot be loaded.
    """
    name = spec.strip()
    in_use = _IN_USE.get(name)
    if in_use is not None and not in_use.plain:
        method = get_method(in_use.source, **{**options, "plugin_kwargs": in_use.kwargs})
        with contextlib.suppress(AttributeError):
            method.name = in_use.name
        return method
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
    """Split a comma list, expand ``all`` or ``paper`` (the paper's seven, and drl when weights are given), drop
    duplicates."""
    items = specs.split(",") if isinstance(specs, str) else list(specs)
    out: list[str] = []
    for raw in items:
        s = raw.strip()
        if not s:
            continue
        if s.lower() in ("all", "paper"):
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
        looks_ahead: the method reads the next step's images (``looks_ahead``: a non-causal control such as the
            oracle, given ``meta["look_ahead"]``); the frame buffer then holds two sequences at least.
    """

    step_cost: int = DEFAULT_STEP_COST
    step_group: str | None = None
    start_up: str | None = None
    looks_ahead: bool = False


def method_traits(spec: str, **options: Any) -> MethodTraits:
    """Check the id ``spec`` as :func:`get_method` does and return what its method declares for scheduling.

    A method class with ``created_in_worker = True`` (creating it starts threads, e.g. torch's) is not created
    here: its ``check_options(**options)`` is called instead and its class attributes are read. Raises
    BracketryError (one line) as :func:`get_method`."""
    in_use = _IN_USE.get(spec.strip())
    factory = _builtin(spec.strip().lower(), options) if in_use is None or in_use.plain else None
    cls = factory.func if isinstance(factory, functools.partial) else factory
    source: Any
    if isinstance(cls, type) and getattr(cls, "created_in_worker", False):
        cls.check_options(**options)  # type: ignore[attr-defined]
        source = cls
    else:
        source = factory() if factory is not None else get_method(spec, **options)
    return MethodTraits(int(getattr(source, "step_cost", DEFAULT_STEP_COST)), getattr(source, "step_group", None),
                        getattr(source, "start_up", None), bool(getattr(source, "looks_ahead", False)))


# -- one name per method -------------------------------------------------------------------------------------------

#: a method's name names folders and files: letters, digits, ``.``, ``_``, ``+``, ``-``, starting with a letter or
#: digit, at most 64 characters
_SAFE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._+-]{0,63}$")
#: names a method cannot take: keywords of --methods / --stats-methods, the files beside the method folders
_RESERVED = {"all", "paper", CONTROLS_KEYWORD, "summary.json", "exposures.csv", "exposure_times.png",
             "closedloop_options.json"}
_REPEAT_SUFFIX = re.compile(r"\.r\d+$")  # the benchmark's repeat folders: <method>.r<n>
_OPTION_KEY = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")

OptionValue = str | int | float | bool | None


@dataclass(frozen=True)
class MethodSpec:
    """One method of a run: its ``name`` (output folders, CSV rows, statistics, plots), the ``source`` it is loaded
    from (a built-in id, ``pkg.module:Class`` or an entry point's name) and the keyword ``options`` its constructor
    gets (sorted ``(key, value)`` pairs; YAML scalars). A built-in's name is its id and it takes no options."""

    name: str
    source: str
    options: tuple[tuple[str, OptionValue], ...] = ()

    @property
    def kwargs(self) -> dict[str, OptionValue]:
        return dict(self.options)

    @property
    def plain(self) -> bool:
        """Whether the name alone loads the method (a built-in, or an entry point named as its method, no
        options)."""
        return self.source == self.name and not self.options

    def to_json(self) -> dict[str, Any]:
        """``{"source": ..., "options": {...}}`` (what, besides the name, decides the method's results)."""
        return {"source": self.source, "options": self.kwargs}

    @classmethod
    def from_json(cls, name: str, doc: Mapping[str, Any]) -> MethodSpec:
        return cls(name, str(doc["source"]), tuple(sorted(dict(doc.get("options") or {}).items())))

    def describe(self) -> str:
        """One line: ``name: source, key=value, ...`` (``name`` alone for a plain method)."""
        if self.plain:
            return self.name
        where = "" if self.source == self.name else self.source
        return f"{self.name}: {', '.join(x for x in (where, _options_text(self.kwargs)) if x)}"


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def _options_text(kwargs: Mapping[str, Any]) -> str:
    return ", ".join(f"{k}={v!r}" for k, v in sorted(kwargs.items()))


def check_method_name(name: str, source: str) -> None:
    """Refuse (one line) a method name that is not a safe folder name."""
    if not _SAFE_NAME.match(name) or name in (".", ".."):
        raise BracketryError(f"AE method {source} is named {name!r}: a method's name names its output folder, so "
                             "use letters, digits, '.', '_', '+' or '-' (starting with a letter or digit, at most 64 "
                             "characters)")
    if name.lower() in _RESERVED or _REPEAT_SUFFIX.search(name):
        raise BracketryError(f"AE method {source} is named {name!r}, which names something else in the outputs "
                             "(all, paper, controls, summary.json, exposures.csv, exposure_times.png, "
                             "closedloop_options.json, <method>.r<n>): rename it")


def is_builtin(name: str) -> bool:
    """Whether ``name`` is a built-in id (``constant-<ms>`` included)."""
    return name.lower() in BUILTIN_METHODS or _CONSTANT.match(name.lower()) is not None


def _load_factory(source: str) -> tuple[Any, str]:
    """The class/factory of a plugin id and the name it falls back on (the attribute after the colon, or the entry
    point's name)."""
    if ":" in source:
        module_name, _, attr = source.partition(":")
        if not module_name or not attr:
            raise BracketryError(f"bad plugin spec {source!r} (use pkg.module:ClassName)")
        try:
            module = importlib.import_module(module_name)
        except ImportError as exc:
            raise BracketryError(f"cannot import AE plugin module {module_name}: {_one_line(exc)}") from exc
        factory: Any = module
        for part in attr.split("."):
            factory = getattr(factory, part, None)
            if factory is None:
                raise BracketryError(f"AE plugin module {module_name} has no {attr}")
        return factory, attr.split(".")[-1]
    eps = _entry_points()
    if source not in eps:
        known = ", ".join([*BUILTIN_METHODS, "constant-<ms>", *sorted(eps)])
        raise BracketryError(f"unknown AE method {source!r} (known: {known}; or a plugin pkg.module:Class)")
    try:
        return eps[source].load(), source
    except Exception as exc:
        raise BracketryError(f"cannot load AE entry point {source} ({eps[source].value}): {_one_line(exc)}") from exc


def resolve_methods(specs: Sequence[str | MethodSpec], options: Mapping[str, Mapping[str, Any]] | None = None,
                    **loader_options: Any) -> list[MethodSpec]:
    """The methods of ``specs`` (ids as :func:`get_method` takes them, or resolved specs kept as they are) with
    their names, checked before any work.

    A built-in's name is its id; a plugin's is its ``name`` attribute (the class's, else the created object's),
    else the attribute after the colon or the entry point's name. ``options``: {method: {keyword: value}} for the
    plugins' constructors, keyed by the method's name or by its id as given (``loader_options``: ``seed``,
    ``parity``, ``drl_weights`` as :func:`get_method`). Each plugin is created once here (so a constructor that
    rejects an option fails now). Raises BracketryError (one line) for an unknown id, an option for an unknown or
    built-in method, a name that is not a safe folder name, and two methods of one name. The keyword ``controls``
    stands for the control rows (:func:`~bracketry_emulator.stats.controls.control_methods`: the non-causal
    oracle and a grid of constant exposures)."""
    options = {str(k): dict(v) for k, v in (options or {}).items()}
    specs = [x for item in specs for x in (control_methods() if isinstance(item, str)
                                           and item.strip().lower() == CONTROLS_KEYWORD else [item])]
    used: set[str] = set()
    out: list[MethodSpec] = []
    for item in specs:
        if isinstance(item, MethodSpec):
            spec = item
        else:
            source = item.strip()
            if is_builtin(source):
                if source in options:
                    raise BracketryError(f"options given for the built-in method {source}: options are for plugins "
                                         "(their constructors' keyword arguments)")
                spec = MethodSpec(source, source)
            else:
                spec = _resolve_plugin(source, options, used, loader_options)
        check_method_name(spec.name, spec.source)
        out.append(spec)
    unknown = sorted(set(options) - used)
    if unknown:
        raise BracketryError(f"options given for methods that are not run: {', '.join(unknown)} (methods: "
                             f"{', '.join(s.name for s in out)})")
    seen: dict[str, MethodSpec] = {}
    for spec in out:
        other = seen.get(spec.name.casefold())
        if other is not None and other != spec:
            raise BracketryError(f"two AE methods are named {spec.name!r} ({other.source} and {spec.source}): a name "
                                 "names a method's outputs, so give one of them another name")
        seen[spec.name.casefold()] = spec
    return list(dict.fromkeys(out))


def is_non_causal(name: str) -> bool:
    """Whether method ``name`` reads the next step's images (a control row, not an AE method)."""
    return name.lower() in NON_CAUSAL_METHODS


def _resolve_plugin(source: str, options: Mapping[str, Mapping[str, Any]], used: set[str],
                    loader_options: Mapping[str, Any]) -> MethodSpec:
    factory, fallback = _load_factory(source)
    class_name = getattr(factory, "name", None) if isinstance(factory, type) else None
    candidate = class_name if isinstance(class_name, str) and class_name else fallback
    key = source if source in options else candidate
    kwargs = dict(options.get(key, {}))
    obj = _instantiate(factory, source, {**loader_options, "plugin_kwargs": kwargs})
    name = obj.name if isinstance(getattr(obj, "name", None), str) and obj.name else candidate
    if key in options:
        used.add(key)
    elif name in options:  # named only once created: create it again with its options
        kwargs = dict(options[name])
        obj = _instantiate(factory, source, {**loader_options, "plugin_kwargs": kwargs})
        used.add(name)
    if name.lower() != source.lower() and is_builtin(name):
        raise BracketryError(f"AE plugin {source} is named {name!r}, the name of a built-in method: rename it")
    return MethodSpec(name, source, tuple(sorted(kwargs.items())))


#: the methods of the run in progress, by name (:func:`methods_in_use`)
_IN_USE: dict[str, MethodSpec] = {}


@contextlib.contextmanager
def methods_in_use(specs: Sequence[MethodSpec]) -> Iterator[None]:
    """While inside, :func:`get_method` and :func:`method_traits` take these methods' names (worker processes
    forked inside inherit them)."""
    before = dict(_IN_USE)
    _IN_USE.update({s.name: s for s in specs})
    try:
        yield
    finally:
        _IN_USE.clear()
        _IN_USE.update(before)


# -- options from the command line ---------------------------------------------------------------------------------

def _check_value(where: str, value: Any) -> OptionValue:
    if value is None or isinstance(value, (str, bool, int)):
        return value
    if isinstance(value, float) and math.isfinite(value):
        return value
    raise BracketryError(f"{where}: an option's value must be a finite number, a string, true/false or null, "
                         f"got {value!r}")


def parse_method_options(pairs: Sequence[str] = (), file: str | Path | None = None) -> dict[str, dict[str, Any]]:
    """Plugin options: ``file`` (YAML ``{method: {key: value}}``) then ``pairs`` (``NAME.key=value``, the value a
    YAML scalar; these win over the file's). Raises BracketryError (one line) on a malformed item."""
    import yaml

    out: dict[str, dict[str, Any]] = {}
    if file is not None:
        try:
            doc = yaml.safe_load(Path(file).read_text())
        except (OSError, yaml.YAMLError) as exc:
            raise BracketryError(f"--method-options {file}: not readable YAML: {_one_line(exc)}") from exc
        if doc is None:
            doc = {}
        if not isinstance(doc, dict):
            raise BracketryError(f"--method-options {file}: expected a mapping {{method: {{key: value}}}}")
        for name, opts in doc.items():
            if not isinstance(opts, dict):
                raise BracketryError(f"--method-options {file}: the options of {name} must be a mapping key: value")
            for key, value in opts.items():
                if not isinstance(key, str) or not _OPTION_KEY.match(key):
                    raise BracketryError(f"--method-options {file}: {name}: option {key!r} is not a keyword name")
                out.setdefault(str(name), {})[key] = _check_value(f"--method-options {file}: {name}.{key}", value)
    for item in pairs:
        lhs, eq, text = item.partition("=")
        name, dot, key = lhs.strip().rpartition(".")
        if not eq or not dot or not name or not _OPTION_KEY.match(key):
            raise BracketryError(f"bad --method-option {item!r} (use NAME.key=value, e.g. median40.target=0.3)")
        try:
            value = yaml.safe_load(text) if text.strip() else ""
        except yaml.YAMLError:
            value = text
        out.setdefault(name, {})[key] = _check_value(f"--method-option {item}", value)
    return out
