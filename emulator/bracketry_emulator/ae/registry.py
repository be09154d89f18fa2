"""Method ids -> AE method objects, and the plugin loader.

Built-in ids: ``fix``, ``ae30``, ``ae50``, ``ae70``, ``shim``, ``wang``, ``kim``, ``zhang``, ``drl``,
``constant-<ms>`` (e.g. ``constant-8``) and the non-causal control ``oracle`` (:mod:`.oracle`). A plugin is
``pkg.module:ClassName`` (any importable class or factory returning an object with the :class:`AEMethod` protocol)
or the name of an entry point in the group ``bracketry.ae_methods``. See PLUGINS.md.

One name per method: :func:`resolve_methods` turns the ids given (and their options) into :class:`MethodSpec`s whose
``name`` (a built-in's id; a plugin's ``name`` attribute) names the output folders, CSV rows, statistics and plots,
refusing unsafe or colliding names before any work. A :class:`MethodSpec` is the method from the command line to the
worker: it carries its source and options (a plugin's constructor arguments, the DRL actor's weights) and creates the
method (:meth:`MethodSpec.create`) wherever it arrives, forked or on another machine (it pickles). The one parser of
``--methods`` is :func:`parse_methods`.
"""

from __future__ import annotations

import contextlib
import functools
import importlib
import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bracketry_base.errors import BracketryError

from ..stats.controls import CONTROLS_KEYWORD, NON_CAUSAL_METHODS, control_methods
from .base import AEMethod
from .classical import ClassicalAE, ConstantExposure, ConvergingFixAE, FixAE

if TYPE_CHECKING:
    from importlib.metadata import EntryPoint

#: The eight methods of the paper, in its table order (``drl`` runs only with its weights, which are not shipped).
PAPER_METHODS: tuple[str, ...] = ("fix", "ae30", "ae50", "ae70", "shim", "wang", "kim", "drl")
#: The keywords of ``--methods`` that stand for :data:`PAPER_METHODS` (drl only with its weights).
PAPER_KEYWORDS: tuple[str, ...] = ("all", "paper")
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


def parse_methods(methods: str | Sequence[str], has_drl_weights: bool = True,
                  warn: Callable[[str], None] | None = None) -> list[str]:
    """The one parser of ``--methods``: a comma list (or a sequence) -> method ids, order kept, duplicates removed.

    ``all`` / ``paper``: the paper's methods (:data:`PAPER_METHODS`; drl only with its weights, ``warn`` says when
    it is left out); ``controls``: the control rows (:func:`~bracketry_emulator.stats.controls.control_methods`: the
    non-causal oracle and a grid of constant exposures); any other item is an id as :func:`get_method` takes it
    (``oracle``, ``zhang``, ``constant-<ms>``, a plugin). Without DRL weights an explicit ``drl`` is an error (one
    line), as is an empty list."""
    items = methods.split(",") if isinstance(methods, str) else list(methods)
    out: list[str] = []
    for item in (str(m).strip() for m in items):
        if not item:
            continue
        if item.lower() == "drl" and not has_drl_weights:
            raise BracketryError("the drl method needs its weights: pass --drl-weights PATH (or set "
                                 "BRACKETRY_DRL_WEIGHTS)")
        if item.lower() in PAPER_KEYWORDS:
            if not has_drl_weights and warn is not None:
                warn(f"note: '{item}' leaves drl out (no --drl-weights given)")
            expanded = [m for m in PAPER_METHODS if m != "drl" or has_drl_weights]
        elif item.lower() == CONTROLS_KEYWORD:
            expanded = list(control_methods())
        else:
            expanded = [item]
        out += [m for m in expanded if m not in out]
    if not out:
        raise BracketryError("no AE method given (e.g. --methods ae50,shim or --methods all)")
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


def method_traits(spec: str | MethodSpec, **options: Any) -> MethodTraits:
    """Check the method ``spec`` (an id as :func:`get_method` takes it, or a resolved :class:`MethodSpec`) and return
    what its method declares for scheduling.

    A method class with ``created_in_worker = True`` (creating it starts threads, e.g. torch's) is not created
    here: its ``check_options(**options)`` is called instead and its class attributes are read. Raises
    BracketryError (one line) as :func:`get_method`."""
    if isinstance(spec, MethodSpec):
        return spec.traits(**options)
    factory = _builtin(spec.strip().lower(), options)
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
    """One method of a run, from the command line to the worker: its ``name`` (output folders, CSV rows,
    statistics, plots), the ``source`` it is loaded from (a built-in id, ``pkg.module:Class`` or an entry point's
    name) and its ``options`` (sorted ``(key, value)`` pairs; YAML scalars): a plugin's constructor keywords, or a
    built-in's own inputs (``drl_weights``: the DRL actor's .pth). A built-in's name is its id. Frozen and
    picklable: forked workers and Dask units get it as it is and create the method from it (:meth:`create`)."""

    name: str
    source: str
    options: tuple[tuple[str, OptionValue], ...] = ()

    @property
    def kwargs(self) -> dict[str, OptionValue]:
        return dict(self.options)

    @property
    def builtin(self) -> bool:
        return is_builtin(self.source)

    @property
    def plain(self) -> bool:
        """Whether the name alone says which method this is (a built-in, whose inputs such as its weights are
        named on their own, or an entry point named as its method, without options)."""
        return self.source == self.name and (not self.options or self.builtin)

    def _loader(self, seed: int, parity: str) -> dict[str, Any]:
        if self.builtin:
            return {"seed": seed, "parity": parity, **self.kwargs}
        return {"seed": seed, "parity": parity, "plugin_kwargs": self.kwargs}

    def create(self, seed: int = 0, parity: str = "default") -> AEMethod:
        """The method itself (a new object; ``seed`` and ``parity``: the closed loop's, see :func:`get_method`)."""
        method = get_method(self.source, **self._loader(seed, parity))
        if not self.builtin:
            with contextlib.suppress(AttributeError):
                method.name = self.name
        return method

    def traits(self, seed: int = 0, parity: str = "default") -> MethodTraits:
        """What the method declares for scheduling (:func:`method_traits`; a plugin is created to read them)."""
        if self.builtin:
            return method_traits(self.source, **self._loader(seed, parity))
        m = self.create(seed, parity)
        return MethodTraits(int(getattr(m, "step_cost", DEFAULT_STEP_COST)), getattr(m, "step_group", None),
                            getattr(m, "start_up", None), bool(getattr(m, "looks_ahead", False)))

    def option(self, key: str) -> OptionValue:
        """One of its options (None when not given)."""
        return self.kwargs.get(key)

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


def resolve_methods(methods: str | Sequence[str | MethodSpec],
                    options: Mapping[str, Mapping[str, Any]] | None = None, *, drl_weights: str | Path | None = None,
                    seed: int = 0, parity: str = "default", warn: Callable[[str], None] | None = None
                    ) -> list[MethodSpec]:
    """The methods of ``methods`` (``--methods`` text or ids, parsed by :func:`parse_methods`; resolved specs are
    kept as they are) with their names, checked before any work: what travels to the workers.

    A built-in's name is its id; a plugin's is its ``name`` attribute (the class's, else the created object's),
    else the attribute after the colon or the entry point's name. ``options``: {method: {keyword: value}} for the
    plugins' constructors, keyed by the method's name or by its id as given. ``drl_weights``: the DRL actor, an
    option of the ``drl`` method (its absolute path); ``seed``, ``parity``: as :func:`get_method`. Each plugin is
    created once here (so a constructor that rejects an option fails now). Raises BracketryError (one line) for an
    unknown id, an option for an unknown or built-in method, a name that is not a safe folder name, and two methods
    of one name."""
    options = {str(k): dict(v) for k, v in (options or {}).items()}
    has_weights = drl_weights is not None
    items: list[str | MethodSpec] = []
    for m in [methods] if isinstance(methods, str) else methods:
        if isinstance(m, MethodSpec):
            items.append(m)
        else:  # groups expanded, duplicates dropped
            items += [p for p in parse_methods(m, has_weights, warn) if p not in items]
    weights = str(Path(drl_weights).resolve()) if drl_weights is not None else None
    loader = {"seed": seed, "parity": parity, "drl_weights": weights}
    used: set[str] = set()
    out: list[MethodSpec] = []
    for item in items:
        if isinstance(item, MethodSpec):
            spec = item
        else:
            source = str(item).strip()
            if is_builtin(source):
                if source in options:
                    raise BracketryError(f"options given for the built-in method {source}: options are for plugins "
                                         "(their constructors' keyword arguments)")
                own = (("drl_weights", weights),) if source.lower() == "drl" and weights is not None else ()
                spec = MethodSpec(source, source, own)
            else:
                spec = _resolve_plugin(source, options, used, loader)
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
