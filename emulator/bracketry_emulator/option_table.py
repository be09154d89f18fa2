"""The settings of the closed loop, the AE methods, SLAM and the benchmark, each declared once (:data:`SETTINGS`).

A :class:`Setting` is one row: the option's name on the command line, its type and unit there, its default and
choices, its help, the commands that take it, the record that receives it (``record``: ``loop`` =
:class:`~bracketry_emulator.ae.runner.LoopConfig`, ``methods`` = the method resolution, ``slam`` =
:class:`~bracketry_emulator.benchmark.slam.SlamOptions`, ``benchmark`` =
:class:`~bracketry_emulator.benchmark.orchestrate.BenchmarkConfig`, ``cluster`` =
:class:`~bracketry_emulator.benchmark.cluster.SlurmOptions`) and its field there, and whether it belongs to the
cache key (``key``: ``always``, ``changed`` = only while it differs from its default, so the keys of runs made
without it stay as they are, or ``never``).

From the rows come, with no second list anywhere: the click options of ``bracketry emulate``, ``bracketry
benchmark`` and ``bracketry demo`` (:func:`options_for`), the values each record receives (:func:`record_values`,
units converted), the records' defaults (:func:`default`), the closed loop's JSON and cache-key form, its checks of
choices and the settings a closed-loop worker receives (:meth:`LoopConfig.to_json`, :meth:`LoopConfig.from_values`:
a loop row without a field of its own reaches the worker as ``settings.loop.value(name)``).

Nothing heavy is imported: the commands read the rows while declaring their options, before numpy loads.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, TypeVar

import click

from bracketry_base.errors import BracketryError
from bracketry_base.options import (
    SEED,
    WORKERS,
    AliasedOption,
    Duration,
    Integer,
    MemorySize,
    Number,
    input_dir,
    input_file,
)

from .defaults import (
    AE_CAMERAS,
    CLUSTERS,
    DEFAULT_ALPHA,
    DEFAULT_CLUSTER_JOBS,
    DEFAULT_CRF,
    DEFAULT_INIT_EXPOSURE_US,
    DEFAULT_MAX_EXPOSURE_US,
    DEFAULT_MIN_EXPOSURE_US,
    DEFAULT_REFERENCE,
    DEFAULT_SLAM_PACE,
    DEFAULT_STATS_METHODS,
    IMAGES,
    MAX_CLUSTER_JOBS,
    MAX_EXPOSURE_OPTION_MS,
    MAX_WARMUP_STEPS,
    PARITIES,
    RUN_IMAGES,
    SELECTIONS,
    SLAM_BACKENDS,
)

EMULATE, BENCHMARK, DEMO = "emulate", "benchmark", "demo"
COMMANDS: tuple[str, ...] = (EMULATE, BENCHMARK, DEMO)
Record = Literal["loop", "methods", "slam", "benchmark", "cluster"]
Key = Literal["always", "changed", "never"]
F = TypeVar("F", bound=Callable[..., Any])
#: a row's ``record_default`` when it has none of its own (its command-line default then, in the record's unit)
_UNSET: Any = type("Unset", (), {"__repr__": lambda self: "UNSET"})()

#: the keywords --methods takes beside method ids (ae/registry.py parse_methods)
METHODS_HELP = ("AE methods: 'all' or 'paper': the paper's seven (fix, ae30, ae50, ae70, shim, wang, kim) and drl "
                "with --drl-weights; 'controls': the oracle and constant exposures; or a comma list of ids (zhang, "
                "constant-<ms> e.g. constant-8, oracle), plugins pkg.module:Class or entry points (each named by its "
                "'name').")


@dataclass(frozen=True)
class Setting:
    """One setting (see the module docstring). ``name``: its click parameter (a Python identifier, unique);
    ``field``: the record's field (default ``name``; ``emulator.<f>`` for a loop setting of the emulator's
    :class:`~bracketry_emulator.emulation.EmulatorConfig`); ``scale``: record value = command-line value x scale
    (``unit`` ms on the command line, us in the record: 1000); ``type``: a click type (None: text; ``bool``: a flag,
    ``off`` its negative spelling); ``default``: on the command line (None: "not given", the record's own default
    :func:`default` applies, which is ``record_default`` when set); ``per_command``: {command: {help, default, choices,
    envvar: ...}} where one command differs; ``convert``: command-line value -> record value (after ``scale``)."""

    name: str
    record: Record
    option: str
    help: str
    default: Any = None
    type: Any = None
    unit: str = ""
    scale: float = 1.0
    choices: tuple[str, ...] = ()
    key: Key = "never"
    commands: tuple[str, ...] = (EMULATE, BENCHMARK)
    field: str = ""
    aliases: tuple[str, ...] = ()
    short: str = ""
    off: str = ""
    envvar: str | None = None
    record_default: Any = _UNSET
    convert: Callable[[Any], Any] | None = None
    per_command: Mapping[str, Mapping[str, Any]] = dataclasses.field(default_factory=dict)

    @property
    def target(self) -> str:
        """The record's field this setting fills."""
        return self.field or self.name

    @property
    def json_name(self) -> str:
        """Its name in the record's JSON form (the field's last part: ``emulator.blur`` -> ``blur``)."""
        return self.target.rsplit(".", 1)[-1]

    def spec(self, command: str) -> dict[str, Any]:
        """The help, default, choices and envvar of the option in ``command``."""
        base = {"help": self.help, "default": self.default, "choices": self.choices, "envvar": self.envvar}
        return {**base, **self.per_command.get(command, {})}

    def record_value(self, value: Any) -> Any:
        """The record's value of a command-line value (scaled, converted)."""
        if self.scale != 1.0:
            value = value * self.scale
        return self.convert(value) if self.convert is not None else value

    @property
    def default_value(self) -> Any:
        """The record's default (``record_default``, else the command-line default in the record's unit)."""
        if self.record_default is not _UNSET:
            return self.record_default
        return None if self.default is None else self.record_value(self.default)


def _windows(text: str) -> tuple[float, ...]:
    """``5:50:1`` (start:stop:step, inclusive) or ``5,10,20`` -> window sizes in metres."""
    try:
        if ":" in text:
            a, b, *rest = (float(x) for x in text.split(":"))
            step = rest[0] if rest else 1.0
            if step <= 0 or b < a:
                raise ValueError
            n = round((b - a) / step) + 1
            return tuple(a + k * step for k in range(n))
        ws = tuple(float(x) for x in text.split(",") if x.strip())
        if not ws or min(ws) <= 0:
            raise ValueError
        return ws
    except ValueError:
        raise BracketryError(f"bad --windows {text!r} (use START:STOP:STEP in metres, or a list like 5,10,20)"
                             ) from None


def slurm_walltime(seconds: float) -> str:
    """``HH:MM:SS`` (Slurm's --time) of ``seconds``, rounded up to whole seconds."""
    import math

    s = math.ceil(seconds)
    return f"{s // 3600:02d}:{s % 3600 // 60:02d}:{s % 60:02d}"


def _text(value: Any) -> Any:
    return None if value is None else str(value)


_EXPOSURE_MS = Number(0.0, MAX_EXPOSURE_OPTION_MS, min_open=True)

#: Every setting shared by the closed-loop commands, once. Order: as ``--help`` lists them.
SETTINGS: tuple[Setting, ...] = (
    # -- the AE methods ----------------------------------------------------------------------------------------
    Setting("methods", "methods", "--methods", METHODS_HELP, "all", short="-m", aliases=("--method",),
            commands=COMMANDS, per_command={EMULATE: {"default": "ae50"},
                                            DEMO: {"help": METHODS_HELP + " ae50 is the demo's reference: keep it."}}),
    Setting("drl_weights", "methods", "--drl-weights",
            "The DRL actor's .pth (ShuyangUni/drl_exposure_ctrl model/actor_drl_feat_10000.pth; env "
            "BRACKETRY_DRL_WEIGHTS). Without it 'all' leaves DRL out.", type=input_file(),
            envvar="BRACKETRY_DRL_WEIGHTS", commands=COMMANDS, convert=_text, key="always"),
    Setting("stats_methods", "benchmark", "--stats-methods",
            "Methods in the statistics and their Bonferroni count: 'paper' (zhang and plugins are reported, not "
            "tested), 'all', or a comma-separated list.", DEFAULT_STATS_METHODS, commands=(BENCHMARK, DEMO)),
    # -- the closed loop ---------------------------------------------------------------------------------------
    Setting("selection", "loop", "--selection", "Closed loops: the emulator's source-bracket selection.",
            SELECTIONS[0], choices=SELECTIONS, key="always", field="emulator.selection"),
    Setting("crf", "loop", "--crf",
            "Closed loops: camera response, 'srgb' or a pcalib.txt file [default: srgb; emulate with --parity "
            "upstream: the dataset's calibration/pcalib*.txt].", key="always", field="emulator.crf",
            record_default=DEFAULT_CRF, convert=str),
    Setting("parity", "loop", "--parity",
            "Closed loops: each method as its paper describes it (default) or as the authors' code runs it "
            "(upstream: their emulation arithmetic, pcalib lifting, truncation, closer_least_sat; shim, kim and zhang "
            "step for step; needs their pcalib: --crf PATH/pcalib_inside1.txt).", PARITIES[0], choices=PARITIES,
            key="always", field="emulator.parity"),
    Setting("ae_camera", "loop", "--ae-camera",
            "Closed loops: the camera whose emulated image the methods see (the authors: left).", AE_CAMERAS[0],
            choices=AE_CAMERAS, key="always"),
    Setting("images", "loop", "--images",
            "Closed loops: emulated images, or the synthetic world's renders at the chosen exposures (truth; "
            "synthetic trajectories only).", IMAGES[0], choices=IMAGES, key="changed",
            per_command={BENCHMARK: {"choices": RUN_IMAGES, "help": (
                "Closed loops: emulated images, the synthetic world's renders at the chosen exposures (truth; "
                "synthetic trajectories only), or both (truth into OUT/truth; OUT/report/truth_agreement.md "
                "compares metrics, rankings and verdicts).")}}),
    Setting("blur", "loop", "--emulate-blur",
            "Closed loops: emulate the motion blur of an exposure longer than its source bracket (optical flow to "
            "the bracket nearest in time; emulator/bracketry_emulator/emulation/blur.py).", False, type=bool,
            key="changed", field="emulator.blur"),
    Setting("init_exposure_us", "loop", "--init-exposure-ms",
            "Closed loops: first target exposure of every method (ms; the authors: 4 ms).",
            DEFAULT_INIT_EXPOSURE_US / 1000.0, type=_EXPOSURE_MS, unit="ms", scale=1000.0, key="always"),
    Setting("min_exposure_us", "loop", "--min-exposure-ms",
            "Closed loops: lower bound applied to every method's output (ms).", DEFAULT_MIN_EXPOSURE_US / 1000.0,
            type=_EXPOSURE_MS, unit="ms", scale=1000.0, key="changed", commands=(EMULATE,)),
    Setting("max_exposure_us", "loop", "--max-exposure-ms",
            f"Closed loops: upper bound applied to every method's output (ms, at most {MAX_EXPOSURE_OPTION_MS:g}).",
            DEFAULT_MAX_EXPOSURE_US / 1000.0, type=_EXPOSURE_MS, unit="ms", scale=1000.0, key="changed",
            commands=(EMULATE,)),
    Setting("seed", "loop", "--seed", "Closed loops: seed of stochastic methods (Kim's GP).", 0, type=SEED,
            key="always"),
    Setting("warmup_steps", "benchmark", "--warmup-steps",
            "Closed loops: steps each method takes on a trajectory's first view before it (not recorded: the walk "
            "starts with a running camera). Default: the manifest's warmup_steps (a synthetic suite declares one), "
            "else 0.", type=click.IntRange(0, MAX_WARMUP_STEPS), commands=(BENCHMARK,)),
    # -- SLAM --------------------------------------------------------------------------------------------------
    Setting("slam_backend", "slam", "--slam", "Localisation: ORB-SLAM3 stereo, or the built-in VO (fast, "
            "deterministic).", SLAM_BACKENDS[0], choices=SLAM_BACKENDS, key="always", field="backend",
            commands=(BENCHMARK, DEMO),
            per_command={DEMO: {"default": None, "help": "Localisation: ORB-SLAM3 stereo, or the built-in VO "
                                "[default: orbslam3; builtin with --quick]."}}),
    Setting("vocabulary", "slam", "--vocabulary",
            "ORB-SLAM3 vocabulary (e.g. ORBvoc.txt; env PYORBSLAM3_VOCAB). Default: the project's own, built once "
            "into the user cache (never downloaded).", type=input_file(), commands=(BENCHMARK,), convert=_text),
    Setting("slam_pace", "slam", "--slam-pace",
            "ORB-SLAM3 feed: 'lockstep' (each frame once ORB-SLAM3's mapping threads are idle: results that do not "
            "move with the machine's load), 'realtime' (the recording's timestamps) or seconds between frames (0 = as "
            "fast as it tracks).", DEFAULT_SLAM_PACE, key="always", field="pace", commands=(BENCHMARK, DEMO)),
    Setting("loop_closing", "slam", "--loop-closing",
            "ORB-SLAM3's loop-closing thread; off also turns relocalisation off.", True, type=bool,
            off="--no-loop-closing", key="always", commands=(BENCHMARK,)),
    Setting("slam_repeats", "slam", "--slam-repeats",
            "SLAM runs per (trajectory, method): the report gives median and spread, statistics use medians.", 1,
            type=Integer(1, 50), field="repeats", commands=(BENCHMARK,)),
    Setting("setup_check", "benchmark", "--setup-check",
            "ORB-SLAM3: before the methods run, check that it tracks the first seconds of a trajectory's middle "
            "bracket (no AE) with this vocabulary and calibration; a failure is one error line, exit 2. Off: for a "
            "dataset whose every trajectory starts unusably (e.g. in darkness).", True, type=bool,
            off="--no-setup-check", commands=(BENCHMARK,)),
    # -- the benchmark -----------------------------------------------------------------------------------------
    Setting("reference", "benchmark", "--reference", "Reference method of the statistics.", DEFAULT_REFERENCE,
            commands=(BENCHMARK,)),
    Setting("alpha", "benchmark", "--alpha", "Significance level before the Bonferroni correction, in (0, 1).",
            DEFAULT_ALPHA, type=Number(0, 1, min_open=True, max_open=True), commands=(BENCHMARK,)),
    Setting("windows_m", "benchmark", "--windows",
            "RTE/RRE windows in metres: START:STOP:STEP or a list. Default: a manifest's windows_m (the demo-size "
            "suite's short walks declare 1-3 m), else 5:50:1 (the paper's).", commands=(BENCHMARK,),
            convert=_windows, key="always"),
    Setting("max_frames", "benchmark", "--max-frames", "Only the first N frames of each run (N >= 2).",
            type=Integer(2), commands=(BENCHMARK,), key="always"),
    Setting("write_images", "benchmark", "--write-images",
            "Also write every emulated image as a PNG under OUT/runs/<trajectory>/<method>/ (default: SLAM gets "
            "them in memory and no PNG is written).", False, type=bool, commands=(BENCHMARK,)),
    Setting("export_orbslam", "benchmark", "--export-orbslam",
            "Also export each run for ORB-SLAM2/3's stereo examples to OUT/orbslam/<trajectory>/<method>/.", False,
            type=bool, commands=(BENCHMARK,)),
    Setting("slam_dir", "benchmark", "--slam-trajectories",
            "Evaluate external SLAM output DIR/<trajectory>/<method>/CameraTrajectory*.txt instead of the built-in "
            "VO.", type=input_dir(), commands=(BENCHMARK,), key="always"),
    Setting("workers", "benchmark", "--workers",
            "Local worker processes, 0 = one per CPU (1 = in this process; ignored on a cluster).", 0, type=WORKERS,
            commands=(BENCHMARK,)),
    Setting("scheduler", "benchmark", "--scheduler",
            "Dask scheduler address tcp://HOST:PORT (default: local processes).", commands=(BENCHMARK,)),
    Setting("cluster", "benchmark", "--cluster",
            "Run on a batch system: Dask workers in at most --jobs jobs (dask-jobqueue), fewer as the work runs "
            "out, all released at the end. Data, output and cache on storage every node sees (docs/CLUSTER.md).",
            choices=CLUSTERS, commands=(BENCHMARK,)),
    Setting("jobs", "cluster", "--jobs", "--cluster: at most this many jobs at once (one Dask worker each).",
            DEFAULT_CLUSTER_JOBS, type=Integer(1, MAX_CLUSTER_JOBS), commands=(BENCHMARK,)),
    Setting("job_cores", "cluster", "--job-cores",
            "--cluster: cores per job (a trajectory's closed loops and SLAM runs share them). Default: "
            "jobqueue.slurm.cores of dask-jobqueue's configuration.", type=Integer(1, 1024), field="cores",
            commands=(BENCHMARK,)),
    Setting("job_memory", "cluster", "--job-memory", "--cluster: memory per job, e.g. 8GB. Default: "
            "jobqueue.slurm.memory.", type=MemorySize(), field="memory", commands=(BENCHMARK,)),
    Setting("job_walltime", "cluster", "--job-walltime",
            "--cluster: walltime per job (e.g. 2h, 90m); a job that hits it has its runs done again by another. "
            "Default: jobqueue.slurm.walltime.", type=Duration(), field="walltime", commands=(BENCHMARK,),
            convert=slurm_walltime),
    Setting("job_partition", "cluster", "--job-partition", "--cluster: Slurm partition. Default: "
            "jobqueue.slurm.queue.", field="partition", commands=(BENCHMARK,)),
    Setting("job_account", "cluster", "--job-account", "--cluster: Slurm account. Default: jobqueue.slurm.account.",
            field="account", commands=(BENCHMARK,)),
)


def settings_for(command: str, table: Iterable[Setting] | None = None) -> list[Setting]:
    """The rows ``command`` takes, in table order."""
    return [s for s in (SETTINGS if table is None else table) if command in s.commands]


def setting(name: str) -> Setting:
    """The row named ``name``."""
    for s in SETTINGS:
        if s.name == name:
            return s
    raise KeyError(name)


def default(record: Record, target: str) -> Any:
    """The default of the field ``target`` of ``record`` (what the record's dataclass declares as its default)."""
    for s in SETTINGS:
        if s.record == record and s.target == target:
            return s.default_value
    raise KeyError(f"{record}.{target}")


def rows(record: Record, table: Iterable[Setting] | None = None) -> list[Setting]:
    """Every row of ``record`` (whatever command takes it)."""
    return [s for s in (SETTINGS if table is None else table) if s.record == record]


def _option(s: Setting, command: str) -> Callable[[F], F]:
    spec = s.spec(command)
    decls = [s.option] + ([s.short] if s.short else []) + list(s.aliases)
    kw: dict[str, Any] = {"help": spec["help"], "envvar": spec["envvar"]}
    if s.type is bool:
        if s.off:
            decls = [f"{s.option}/{s.off}"]
        else:
            kw["is_flag"] = True
        kw["default"] = bool(spec["default"])
        kw["show_default"] = bool(s.off)
    else:
        kw["default"] = spec["default"]
        kw["show_default"] = spec["default"] is not None
        kw["type"] = click.Choice(spec["choices"]) if spec["choices"] else s.type
    return click.option(*decls, s.name, cls=AliasedOption, aliases=s.aliases, **kw)


def options_for(command: str, table: Iterable[Setting] | None = None) -> Callable[[F], F]:
    """The click options of every row ``command`` takes (``table``: :data:`SETTINGS`), in table order."""
    chosen = settings_for(command, table)

    def decorate(f: F) -> F:
        for s in reversed(chosen):
            f = _option(s, command)(f)
        return f
    return decorate


def record_values(command: str, given: Mapping[str, Any], record: Record,
                  table: Iterable[Setting] | None = None) -> dict[str, Any]:
    """{field: value} of ``record`` from a command's parsed options ``given`` (click's parameters by row name), in
    the record's units; an option left at None (not given) is left out, so the record's default applies."""
    out: dict[str, Any] = {}
    for s in settings_for(command, table):
        if s.record != record or s.name not in given or given[s.name] is None:
            continue
        out[s.target] = s.record_value(given[s.name])
    return out


def pop_settings(command: str, given: dict[str, Any], table: Iterable[Setting] | None = None) -> dict[str, Any]:
    """Take the rows' parameters out of a command's keyword arguments ``given`` (what is left: the command's own)."""
    return {s.name: given.pop(s.name) for s in settings_for(command, table) if s.name in given}


def option_text(value: Any) -> str:
    """A record value as the command line spells it (for messages)."""
    return str(value) if not isinstance(value, Path) else value.as_posix()
