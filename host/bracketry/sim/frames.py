"""Pixels for the simulated cameras: frame k of the bracket cycle, rendered ahead by a separate process, each frame
carrying its own index.

Frame k of a side is the synthetic world exposed ``brackets[k % n]`` from its own trigger instant ``k / fps``
(:func:`trigger_time_s`), with the motion blur of that interval; its pose is the camera's at its mid-exposure
instant (:func:`frame_time_s`). Each bracket cycle is ray cast once, at the middle of the cycle's span
(:func:`reference_time_s`), and that render is reprojected by its range to each bracket's instants
(``World.rates_e_per_us``, :mod:`bracketry_emulator.synth.blur`): six full renders per cycle would not keep up
with the triggers on two cores. One renderer process per side
(:func:`render_frames`, started by :meth:`FrameSchedule.start`) writes the frames in order into one shared memory
file per side and counts them in a small shared counter, so the rig starts recording while later frames are still
being rendered. The fake camera's image source serves each side its next bracket frame, by count (the k-th bracket
frame a camera fills is frame k, as the pairer gives the k-th frame a camera took the k-th pulse), so both images of
a stereo pair show the same rendered frame whatever the load; the exposure the camera reports only moves the count
when two fills in a row show it off (see :meth:`FrameSchedule.source`), and a fill whose exposure is not in the
bracket cycle (the priming trigger) gets no frame.

Identity, not timing: every served frame carries the index k of the rendered frame it shows, written into its first
:data:`FRAME_ID_PIXELS` pixels (row 0) by :func:`embed_frame_id`; :func:`read_frame_id` reads it back from a
recorded image. The ground truth of a recorded frame is the pose at world time ``frame_time_s(k)`` of that k, so
merged or dropped triggers, late buffers and a loaded machine cannot give a frame another frame's pose. A frame
served without a rendered image (the renderer far behind, an exposure outside the bracket cycle such as the priming
trigger) has no identity: its pose is unknown and reported, never guessed.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import multiprocessing.connection
import os
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bracketry.sim.clock import MONOTONIC, Clock

ProgressFn = Callable[[int, int], None]

#: the renderer's noise: a frame's Gaussian noise is a window, at a random place, of this many frames' worth of
#: standard normal variates drawn once per side (drawing them per frame cost more than half of exposing one)
NOISE_BANK_FRAMES = 16
#: fills in a row a side must come most of a period after the other side's before it is taken to have missed a
#: trigger (the pairer's twice ``confirm_frames`` for host-fired cameras)
MISSED_CONFIRM_FRAMES = 6
#: environment of the renderer processes: one BLAS thread each. The ray caster's one matrix product per frame
#: (3 x 3 by 3 x H*W) would otherwise run on a pool of a thread per core whose threads spin waiting for each other:
#: on this 2-core machine with the other core busy, 41 instead of 20 ms of CPU per 640x400 render (the same values)
RENDERER_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
#: pixels of row 0 holding a frame's identity (three data codes and a check code, 12-bit values)
FRAME_ID_PIXELS = 4
_TAGS = (0xA00, 0x500, 0xC00, 0x300)
#: largest index a frame can carry (24 bits)
MAX_FRAME_ID = (1 << 24) - 1
#: how long the image source waits for the renderer before serving a frame without identity, seconds (short: a camera
#: blocked in its image source delivers late and merges triggers, which confuses the pairing of the frames)
WAIT_FOR_RENDER_S = 0.02
#: the longest a wait for the renderer sleeps without looking again (a safety net: each frame rendered, and a
#: renderer's exit, wakes it)
SAFETY_WAKE_S = 1.0


def embed_frame_id(image: np.ndarray, k: int) -> None:
    """Write index ``k`` (0..2**24-1) into ``image[0, :4]`` (uint16 (H, W), 12-bit codes) in place."""
    if not 0 <= k <= MAX_FRAME_ID:
        raise ValueError(f"frame index {k} outside 0..{MAX_FRAME_ID}")
    b = ((k >> 16) & 0xFF, (k >> 8) & 0xFF, k & 0xFF)
    check = b[0] ^ b[1] ^ b[2] ^ 0x5A
    image[0, :FRAME_ID_PIXELS] = (_TAGS[0] | b[0], _TAGS[1] | b[1], _TAGS[2] | b[2], _TAGS[3] | check)


def clear_frame_id(image: np.ndarray) -> None:
    """Remove any identity from ``image`` (a frame whose pose is not known)."""
    image[0, :FRAME_ID_PIXELS] = 0


def read_frame_id(image: np.ndarray) -> int | None:
    """The index a frame carries (see :func:`embed_frame_id`), or None when it carries none.

    ``image``: uint16 (H, W) as served (12-bit codes); also accepts codes scaled to 16 bits (``<< 4``)."""
    if image.ndim != 2 or image.shape[1] < FRAME_ID_PIXELS:
        return None
    px = [int(v) for v in image[0, :FRAME_ID_PIXELS]]
    if max(px) > 0xFFF and all(v & 0xF == 0 for v in px):
        px = [v >> 4 for v in px]
    if any(v & 0xF00 != t for v, t in zip(px, _TAGS)):
        return None
    b = [v & 0xFF for v in px]
    if b[0] ^ b[1] ^ b[2] ^ 0x5A != b[3]:
        return None
    return (b[0] << 16) | (b[1] << 8) | b[2]


@dataclass
class WorldSpec:
    """What the renderer process builds its world from (a ``bracketry_emulator.synth.World``); None: test pattern."""

    preset: str = "forest-winter"
    seed: int = 0


@dataclass
class FrameSchedule:
    """The frames of both sides in shared memory files under ``folder``, rendered ahead by a separate process.

    ``world``: the spec of the synthetic world (None: a moving test pattern, for rigs without the emulator extra);
    ``brackets_us``: the exposure cycle; ``fps``: the trigger rate; ``n_frames`` per side (frames beyond repeat,
    each still carrying its own index k mod n_frames). ``frames[side]`` is a uint16 (n_frames, height, width)
    memory map of 12-bit Bayer codes, valid up to :meth:`rendered`.
    """

    folder: Path
    world: WorldSpec | None
    brackets_us: Sequence[int]
    fps: float
    n_frames: int
    resolution: tuple[int, int] = (640, 400)
    sides: Sequence[str] = ("left", "right")
    wait_for_render_s: float = WAIT_FOR_RENDER_S
    #: the time of fills (see ``_follow_missed_trigger``) and the waits' deadlines
    clock: Clock = MONOTONIC
    frames: dict[str, np.ndarray] = field(default_factory=dict, init=False)
    #: per side, how many bracket frames were served (the next one is bracket frame ``served[side]``), and how many
    #: frames without identity
    served: dict[str, int] = field(default_factory=dict, init=False)
    unidentified: dict[str, int] = field(default_factory=dict, init=False)
    #: per side, frames the camera had to wait for (the renderer was behind the triggers)
    waited: dict[str, int] = field(default_factory=dict, init=False)
    #: bracket frames whose camera filled them with another exposure than their own (a late fill, see ``source``)
    mismatches: int = field(default=0, init=False)
    #: times a side's count skipped a frame: its fills came a period after the other side's (a missed trigger)
    resyncs: int = field(default=0, init=False)
    #: bracket frames served from an earlier rendered cycle because the renderer was behind (the world held)
    held: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        self.folder = Path(self.folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.brackets_us = [int(b) for b in self.brackets_us]
        self.width, self.height = self.resolution
        shape = (int(self.n_frames), self.height, self.width)
        for side in self.sides:
            self.frames[side] = np.lib.format.open_memmap(self.frame_path(side), mode="w+", dtype=np.uint16,
                                                          shape=shape)
            self.served[side] = 0
            self.unidentified[side] = 0
            self.waited[side] = 0
        #: per side: [frames rendered, renderer state: 0 running, 1 done, 2 failed, time.time_ns() when done]
        self._counter = np.lib.format.open_memmap(self.folder / "rendered.npy", mode="w+", dtype=np.int64,
                                                  shape=(len(self.sides), 3))
        self._lock = threading.Lock()
        self._chosen: dict[int, int] = {}
        #: per side: fill time (on ``clock``) of its recent bracket frames, and its run of fills later than the
        #: other side's by most of a period (see _follow_missed_trigger)
        self._fill_s: dict[str, dict[int, float]] = {}
        self._late_run: dict[str, int] = {}
        self._procs: list[Any] = []
        #: notified when a renderer reports a frame or ends (see ``_watch``)
        self._progressed = threading.Condition()
        self._watcher: threading.Thread | None = None

    def frame_path(self, side: str) -> Path:
        return self.folder / f"frames_{side}.npy"

    # ----------------------------------------------------------------------------------------------- timing
    def t_s(self, k: int) -> float:
        """World time of frame k's pose, seconds: its mid-exposure instant (see :func:`frame_time_s`)."""
        return frame_time_s(k, self.brackets_us, self.fps)

    def exposure_us(self, k: int) -> int:
        """Exposure of frame k, microseconds."""
        return int(self.brackets_us[k % len(self.brackets_us)])

    # ----------------------------------------------------------------------------------------------- rendering
    def start(self) -> FrameSchedule:
        """Start the renderer processes, one per side (returns at once; see :meth:`rendered` and :meth:`wait`).

        One process per side: both cores when the machine is idle, and twice the share of a loaded one."""
        ctx = multiprocessing.get_context("spawn")  # the rig process runs GLib threads: never fork it
        readers = []
        for side in self.sides:
            reader, writer = ctx.Pipe(duplex=False)
            proc = ctx.Process(target=render_frames, name=f"bracketry-render-{side}", daemon=True,
                               args=(str(self.folder), self.world, list(self.brackets_us), self.fps,
                                     int(self.n_frames), self.resolution, [side], list(self.sides), writer))
            with _environment(RENDERER_ENV):  # read by the child's BLAS when it loads
                proc.start()
            writer.close()  # the child's copy is the only one: its exit ends the pipe
            self._procs.append(proc)
            readers.append(reader)
        self._watcher = threading.Thread(target=self._watch, args=(readers, [p.sentinel for p in self._procs]),
                                         name="bracketry-render-watch", daemon=True)
        self._watcher.start()
        return self

    def _watch(self, readers: list[Any], sentinels: list[int]) -> None:
        """Wake the waits for the renderer whenever a renderer reports a frame (one message per frame on its pipe) or
        ends (its process sentinel); returns once every renderer has ended."""
        waiting: list[Any] = [*readers, *sentinels]
        while waiting:
            for ready in multiprocessing.connection.wait(waiting):
                waited: Any = ready  # a reader (Connection) or a sentinel (int)
                if waited in sentinels:
                    waiting.remove(waited)
                    continue
                try:
                    waited.recv_bytes()
                except (EOFError, OSError):
                    waiting.remove(waited)
            with self._progressed:
                self._progressed.notify_all()
        for reader in readers:
            reader.close()

    def rendered(self) -> int:
        """Frames rendered so far on every side."""
        return int(self._counter[:, 0].min())

    def render_done_ns(self) -> int | None:
        """Host time (``time.time_ns()``) when the last frame was rendered, None while rendering."""
        return int(self._counter[:, 2].max()) if bool((self._counter[:, 1] == 1).all()) else None

    def failed(self) -> bool:
        return bool((self._counter[:, 1] == 2).any()) or any(p.exitcode not in (None, 0) for p in self._procs)

    def wait(self, progress: ProgressFn | None = None, timeout_s: float | None = None,
             frames: int | None = None) -> None:
        """Block until ``frames`` (default: every frame) are rendered (``progress(done, total)`` on the way)."""
        deadline = None if timeout_s is None else self.clock.now_s() + timeout_s
        wanted = self.n_frames if frames is None else min(int(frames), self.n_frames)
        while self.rendered() < wanted:
            if self.failed():
                raise RuntimeError(f"the frame renderer failed (see {self.folder}/render_*.log)")
            now = self.clock.now_s()
            if deadline is not None and now > deadline:
                raise TimeoutError(f"frames not rendered within {timeout_s:g} s")
            if progress is not None:
                progress(self.rendered(), self.n_frames)
            with self._progressed:  # woken by the next frame rendered (or a renderer's end)
                self._progressed.wait_for(lambda: self.rendered() >= wanted or self.failed(),
                                          SAFETY_WAKE_S if deadline is None else
                                          min(SAFETY_WAKE_S, max(0.0, deadline - now) + 1e-3))
        if progress is not None:
            progress(wanted, self.n_frames)

    def stop(self) -> None:
        """End the renderer processes (if still running)."""
        procs, self._procs = self._procs, []
        for proc in procs:
            if proc.is_alive():
                proc.terminate()
        for proc in procs:
            proc.join(10)
        watcher, self._watcher = self._watcher, None
        if watcher is not None:
            watcher.join(10)  # ends with the renderers

    # ----------------------------------------------------------------------------------------------- serving
    def _frame(self, side: str, k: int) -> np.ndarray | None:
        """Rendered frame k of ``side`` (waits for the renderer up to ``wait_for_render_s``), or None."""
        k %= self.n_frames
        if self.rendered() <= k:
            with self._lock:
                self.waited[side] += 1
            with self._progressed:  # woken by each frame rendered (or a renderer's end)
                self._progressed.wait_for(lambda: self.rendered() > k or self.failed(), self.wait_for_render_s)
            if self.rendered() <= k:
                return None
        return self.frames[side][k]

    def choose(self, m: int) -> int | None:
        """The rendered frame served for bracket frame ``m`` of the trigger sequence (the same for both sides):
        ``m`` itself when rendered, else the latest rendered frame with the same exposure (the world waits for the
        renderer instead of the camera: no trigger is delayed), None when none is rendered yet. Call with the lock
        held."""
        k = self._chosen.get(m)
        if k is None:
            n, r = len(self.brackets_us), self.rendered()
            if m < r or r == self.n_frames:  # rendered (frames beyond n_frames repeat the rendered ones)
                k = m
            else:
                k = m % n + ((r - 1 - m % n) // n) * n if r > m % n else -1
                k = None if k < 0 else k
                if k is not None:
                    self.held += 1
            if k is not None:
                self._chosen[m] = k
                for old in [key for key in self._chosen if key < m - 8 * n]:
                    del self._chosen[old]
        return k

    def _follow_missed_trigger(self, side: str, m: int, now_s: float) -> None:
        """The pairer's rule for a camera that took one trigger for two, on fill times (the fake camera stamps a frame
        when it fills it): when :data:`MISSED_CONFIRM_FRAMES` fills in a row of ``side`` came at least 0.7 period
        after the other side's fills of the same bracket frames, ``side`` missed a trigger; its later fills skip one
        frame, as the pairer moves its later frames on by one pulse. Call with the lock held."""
        fills = self._fill_s.setdefault(side, {})
        fills[m] = now_s
        for old in [key for key in fills if key < m - 64]:
            del fills[old]
        others = [self._fill_s.get(o, {}).get(m) for o in self.sides if o != side]
        known = [t for t in others if t is not None]
        if not known:
            return
        if now_s - min(known) >= 0.7 / self.fps:
            self._late_run[side] = self._late_run.get(side, 0) + 1
            if self._late_run[side] >= MISSED_CONFIRM_FRAMES:
                self._late_run[side] = 0
                self.served[side] += 1
                self.resyncs += 1
        else:
            self._late_run[side] = 0
        for other in self.sides:  # a side that filled this frame before this one was not late with it
            if other != side and m in self._fill_s.get(other, {}):
                self._late_run[other] = 0

    def source(self, side: str) -> Callable[[int, int, int], np.ndarray]:
        """The fake camera image source of ``side``: (exposure_us, width, height) -> uint16 (height, width)."""

        def fill(exposure_us: int, width: int, height: int) -> np.ndarray:
            with self._lock:
                matched = k = None
                if any(abs(b - exposure_us) <= 1 for b in self.brackets_us):
                    # the side's next bracket frame, by count: the pairer counts this camera's frames the same way
                    # (one per trigger it took). The exposure only tells bracket frames from others: the fake camera
                    # reads its exposure register when it fills a frame, and a late fill finds the next pulse's
                    # exposure already written (a real sensor latches it at the trigger)
                    if side not in self._fill_s:
                        # this side's first bracket frame: the camera may have lost the first trigger(s) of the
                        # acquisition, so its place in the cycle is its exposure's (the pairer places the first frame
                        # by its timestamp the same way)
                        c = self.served[side]
                        self.served[side] = next((c + j for j in range(len(self.brackets_us))
                                                  if abs(self.exposure_us(c + j) - exposure_us) <= 1), c)
                    matched = self.served[side]
                    self.mismatches += abs(self.exposure_us(matched) - exposure_us) > 1
                    self._follow_missed_trigger(side, matched, self.clock.now_s())
                    self.served[side] += 1
                    k = self.choose(matched)
            frame = None
            if matched is not None:
                if k is None:  # nothing of that exposure rendered yet: wait a moment for the renderer
                    frame = self._frame(side, matched)
                    k = matched if frame is not None else None
                else:
                    frame = self.frames[side][k % self.n_frames]
            out = np.zeros((height, width), np.uint16)
            if frame is not None:
                h, w = min(height, frame.shape[0]), min(width, frame.shape[1])
                out[:h, :w] = frame[:h, :w]
            else:  # not a bracket frame (e.g. the priming trigger) or nothing rendered
                with self._lock:
                    self.unidentified[side] += 1
            if frame is None or matched is None:
                clear_frame_id(out)
            return out

        return fill


@contextlib.contextmanager
def _environment(values: dict[str, str]) -> Iterator[None]:
    """``os.environ`` with ``values`` where not set already (a child started inside inherits them), then restored."""
    added = {k: v for k, v in values.items() if k not in os.environ}
    os.environ.update(added)
    try:
        yield
    finally:
        for k in added:
            os.environ.pop(k, None)


def trigger_time_s(k: int, fps: float) -> float:
    """World time of frame k's trigger, seconds: ``k / fps`` (its exposure is [k / fps, k / fps + exposure])."""
    return k / fps


def frame_time_s(k: int, brackets_us: Sequence[float], fps: float) -> float:
    """World time of frame k's ground-truth pose: its mid-exposure instant, ``k / fps + brackets[k % n] / 2``."""
    return trigger_time_s(k, fps) + 0.5e-6 * float(brackets_us[k % len(brackets_us)])


def reference_time_s(cycle: int, brackets_us: Sequence[float], fps: float) -> float:
    """World time of the one render of bracket cycle ``cycle``: the middle of its span, from its first trigger to the
    end of its last exposure (the reprojection to each bracket moves the image as little as it can)."""
    n = len(brackets_us)
    first = trigger_time_s(cycle * n, fps)
    last_end = trigger_time_s(cycle * n + n - 1, fps) + 1e-6 * float(brackets_us[-1])
    return 0.5 * (first + last_end)


def cycle_rates(world: Any, side: str, cycle: int, brackets_us: Sequence[float], fps: float,
                renders: str = "cycle") -> list[np.ndarray]:
    """Expected photo-electrons per microsecond (float32 (H, W)) of each frame of bracket cycle ``cycle`` of ``side``
    (a ``bracketry_emulator.synth.World``): bracket j exposed from its own trigger with its own blur.

    ``renders``: "cycle" (the rig's: one render per cycle at :func:`reference_time_s`, reprojected to each bracket's
    instants) or "frame" (one render per frame at its mid-exposure, reprojected within its exposure: the offline
    writer's, six times the ray casting)."""
    n = len(brackets_us)
    intervals = [(trigger_time_s(cycle * n + j, fps), float(brackets_us[j])) for j in range(n)]
    if renders == "frame":
        return world.rates_e_per_us(side, intervals)
    return world.rates_e_per_us(side, intervals, t_ref_s=reference_time_s(cycle, brackets_us, fps))


def _pattern(side: str, k: int, exposure_us: float, width: int, height: int) -> np.ndarray:
    yy, xx = np.mgrid[0:height, 0:width]
    shift = 8 * k + (12 if side == "right" else 0)
    pattern = ((xx + shift) // 16 + yy // 16) % 2 * 0.8 + 0.1
    return np.clip(pattern * exposure_us / 8.0, 0, 4094).astype(np.uint16)


def noise_bank(world: Any, side_index: int) -> np.ndarray:
    """The standard normal variates of one side's frames (float32, (NOISE_BANK_FRAMES + 1) * W * H): drawn once,
    each frame's noise is a window of them (see :func:`expose_frame`)."""
    w, h = world.resolution
    rng = np.random.default_rng(np.random.SeedSequence([world.seed, side_index, NOISE_BANK_FRAMES]))
    return rng.standard_normal((NOISE_BANK_FRAMES + 1) * w * h, dtype=np.float32)


def expose_frame(world: Any, bank: np.ndarray, side: str, rate_e_per_us: np.ndarray, t_s: float,
                 exposure_us: float) -> np.ndarray:
    """The rig's frame of ``side`` (a ``bracketry_emulator.synth.World``) triggered at world time ``t_s``, exposed
    ``exposure_us`` at ``rate_e_per_us`` (see :func:`cycle_rates`): uint16 (H, W) 12-bit codes, its noise the window
    of ``bank`` (see :func:`noise_bank`) at a place drawn from the frame's own generator."""
    w, h = world.resolution
    at = int(world.frame_rng(side, t_s, exposure_us).integers(0, NOISE_BANK_FRAMES * w * h))
    return world.camera.expose(rate_e_per_us, exposure_us, None, normal=bank[at:at + w * h])


def world_frame(world: Any, bank: np.ndarray, side: str, t_s: float, exposure_us: float) -> np.ndarray:
    """One frame of ``side`` triggered at ``t_s`` and exposed ``exposure_us`` from its own render (reprojected within
    its exposure), exposed as :func:`expose_frame` does."""
    return expose_frame(world, bank, side, world.rate_e_per_us(side, t_s, exposure_us), t_s, exposure_us)


def render_frames(folder: str, world_spec: WorldSpec | None, brackets_us: list[int], fps: float, n_frames: int,
                  resolution: tuple[int, int], sides: list[str], all_sides: list[str] | None = None,
                  progress: Any = None) -> None:
    """A renderer process: frame k of each of ``sides``, k = 0, 1, ..., into the shared files, counting as it goes
    (in the counter rows of those sides among ``all_sides``, default ``sides``) and, given ``progress`` (the
    writing end of a ``multiprocessing.Pipe``), telling the rig there after each frame."""
    parent = os.getppid()
    # its own session: with the kernel's autogroup scheduling, a session's processes share one CPU share, so the
    # renderer competes with other sessions' load rather than with the rig it feeds (which has its own)
    with contextlib.suppress(OSError):
        os.setsid()
    base = Path(folder)
    counter = np.load(base / "rendered.npy", mmap_mode="r+")
    rows = [(all_sides or sides).index(s) for s in sides]
    frames = {s: np.load(base / f"frames_{s}.npy", mmap_mode="r+") for s in sides}
    try:
        world = None
        if world_spec is not None:
            from bracketry_emulator.synth import World

            world = World(world_spec.preset, seed=world_spec.seed, resolution=resolution)
        w, h = resolution
        banks = {}
        if world is not None:  # standard normal variates drawn once: each frame's noise is a window of them
            for side in sides:
                banks[side] = noise_bank(world, (all_sides or sides).index(side))
        n = len(brackets_us)
        rates: dict[str, list[np.ndarray]] = {}
        for k in range(n_frames):
            if k % 64 == 0 and os.getppid() != parent:
                return  # the rig process is gone (killed): outside its process group, nobody else ends us
            t_s, exp_us = trigger_time_s(k, fps), float(brackets_us[k % n])
            for side in sides:
                if world is not None:
                    if k % n == 0 or side not in rates:  # the cycle's one render, reprojected to its brackets
                        rates[side] = cycle_rates(world, side, k // n, brackets_us, fps)
                    img = expose_frame(world, banks[side], side, rates[side][k % n], t_s, exp_us)
                else:
                    img = _pattern(side, k, exp_us, w, h)
                embed_frame_id(img, k)
                frames[side][k] = img
            if k == n_frames - 1:  # done before the last frame is counted: whoever sees it counted sees it done
                counter[rows, 2] = time.time_ns()
                counter[rows, 1] = 1
            counter[rows, 0] = k + 1
            if progress is not None:
                try:
                    progress.send_bytes(b"")
                except BrokenPipeError:
                    return  # the rig process is gone
        if n_frames == 0:
            counter[rows, 2] = time.time_ns()
            counter[rows, 1] = 1
    except BaseException as exc:
        counter[rows, 1] = 2
        (base / f"render_{'_'.join(sides)}.log").write_text(f"{type(exc).__name__}: {exc}\n")
        raise


def groundtruth_lines(world: Any, t_s: Callable[[int], float], frames: Sequence[tuple[int, int | None]]
                      ) -> tuple[list[str], int]:
    """TUM lines of recorded frames ``(stamp_ns, carried index k or None)``: each known frame gets the pose of the
    world at ``t_s(k)``. Returns (lines, number of frames without a known pose)."""
    from bracketry_emulator.synth.writer import tum_line

    lines = ["# bracketry simulated rig ground truth (TUM): t_s tx ty tz qx qy qz qw, left camera, host time; "
             "each pose from the rendered frame index the recorded image carries"]
    unknown = 0
    for t_ns, k in frames:
        if k is None:
            unknown += 1
            continue
        lines.append(tum_line(int(t_ns), world.pose(t_s(k))))
    return lines, unknown
