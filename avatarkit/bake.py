"""`bake(avatar, clip, config) -> (BakeStatic, frames)`: an avatar driven by a motion clip, one
frame at a time (the paper's Algorithm 1 at inference).

Per frame: the head mesh by LBS (`HeadModel.forward` on the clip's pose and expression with the
AVATAR's identity shape; a clip's own `shape` is ignored, since the Gaussians, hair and cage were
fitted to the avatar's head); the bald Gaussians carried by their triangles
(`TriangleBinding`: mu = k R mu' + t, q = q_R q', s = k s'); the hair cage stepped by XPBD
(`HairDriver`: roots follow the posed scalp, proxy collision with the posed head) and the hair
Gaussians moved through the cage (`CageDeformer`, mean value coordinates).

Streaming: `frames` is a lazy iterator working in chunks of `BakeConfig.hair_batch` frames
(16): the head is posed and the cage stepped for a chunk, the hair of the whole chunk is
deformed in one product (the per-frame cost of the hair drops ~4x against one product per
frame), then its frames are yielded one by one. Only one chunk's arrays are alive at a time, so
memory does not grow with the clip; `hair_batch=1` is the simple one-frame-at-a-time reference. `run_bake` feeds one pass
of it to any number of writers (USD stage, PLY sequence, preview video), each with the shape
`begin(static)`, `write(frame)`, `close()`, `abort()`.

Frame numbers: `BakeConfig.frames = (a, b)` selects frames a..b-1 of the clip (after `fps`
resampling); the output's frames are numbered from 0 (USD time code 0 is clip frame a; the
provenance records a and b). The hair is still simulated from the clip's first frame, so frame
k of a ranged bake equals frame a + k of the full bake. Before the first simulated frame the
hair settles for `preroll` seconds at that pose (`SimConfig.warmup_seconds` by default).

A hairless avatar (`Avatar.has_hair` False) bakes its head only: no simulation; its frames'
hair is empty (0 Gaussians) and so is the cage (`BakeStatic.cage_faces` (0, 3), frame
`cage_vertices` (0, 3)); the writers then leave the hair and the cage out.

View-dependent colour: `BakeStatic` holds one set of SH coefficients; a bald avatar whose SH
bands turn with their triangles (sh_frame "local", degree > 0) is baked with its rest-pose SH.
"""
import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Sequence

import numpy as np

from avatarkit.baked import BakeFrame, BakeStatic, SplatFrame
from avatarkit.errors import InputError
from avatarkit.limits import MAX_FPS, MAX_PREROLL_SECONDS, MIN_FPS
from avatarkit.rig.binding_kernel import binding_to_world
from avatarkit.sim.config import SimConfig

#: frames posed per call of the head model (LBS is cheaper batched; bounds memory)
POSE_CHUNK = 8
#: default `BakeConfig.hair_batch`: frames of hair deformed in one (3 T, C) x (C, P) product.
#: The product is compute-bound for one frame (W is read for 3 rows); at 16 frames per read of
#: W it costs ~1/4 of the single-frame CPU time per frame (benchmarks/cage.py, bake.py)
HAIR_BATCH = 16
#: a clip whose translation goes further than this (metres) is not in metres
MAX_TRANSLATION = 10.0


@dataclass(frozen=True)
class BakeConfig:
    """What to bake and how to simulate it.

    frames: (start, stop) frame range of the clip, Python slice rules (stop None = to the end,
    negatives count from the end), after resampling to `fps`; None bakes every frame.
    fps: resample the clip to this frame rate (quaternion slerp); None keeps the clip's.
    sim: the hair simulation's `SimConfig` (substeps, iterations, gravity, collision, static).
    preroll: seconds the hair settles at the first pose before the clip starts (None:
    `sim.warmup_seconds`).
    hair_batch: frames simulated ahead and deformed in one product (memory ~ 1.2 MB per frame
    per 50k hair Gaussians). 1 is the simple reference path (one product per frame); any value
    gives the same frames up to float32 rounding of the product (~1e-7 m).
    """

    frames: tuple[int, int | None] | None = None
    fps: float | None = None
    sim: SimConfig = field(default_factory=SimConfig)
    preroll: float | None = None
    hair_batch: int = field(default_factory=lambda: HAIR_BATCH)  # read when the config is made

    def __post_init__(self):
        if self.frames is not None:
            try:
                start, stop = self.frames
                start = int(start)
                stop = None if stop is None else int(stop)
            except (TypeError, ValueError):
                raise InputError(f"frames must be (start, stop), got {self.frames!r}") from None
            object.__setattr__(self, "frames", (start, stop))
        if self.fps is not None and not (isinstance(self.fps, (int, float)) and math.isfinite(self.fps)
                                         and MIN_FPS <= self.fps <= MAX_FPS):
            raise InputError(f"fps must be a number between {MIN_FPS:g} and {MAX_FPS:g}, got {self.fps!r}")
        if not isinstance(self.sim, SimConfig):
            raise InputError("sim must be a SimConfig")
        if self.preroll is not None and not (math.isfinite(self.preroll)
                                             and 0 <= self.preroll <= MAX_PREROLL_SECONDS):
            raise InputError(f"preroll must be between 0 and {MAX_PREROLL_SECONDS:g} seconds, got {self.preroll!r}")
        if isinstance(self.hair_batch, bool) or not isinstance(self.hair_batch, (int, np.integer)) \
                or not 1 <= self.hair_batch <= 1024:
            raise InputError(f"hair_batch must be an integer in 1..1024, got {self.hair_batch!r}")
        object.__setattr__(self, "hair_batch", int(self.hair_batch))

    @staticmethod
    def parse_frames(text: str) -> tuple[int, int | None]:
        """"A:B" (A..B-1), "A:" (A to the end), ":B" or "N" (frame N only) -> (start, stop)."""
        s = str(text).strip()
        try:
            if ":" not in s:
                n = int(s)
                return n, (n + 1 if n != -1 else None)
            a, b = s.split(":")
            return (int(a) if a.strip() else 0), (int(b) if b.strip() else None)
        except ValueError:
            raise InputError(f"cannot read frame range {text!r}: use A:B (frames A..B-1), A: or :B") from None

    def to_json(self) -> dict:
        return {"frames": None if self.frames is None else list(self.frames), "fps": self.fps,
                "preroll": self.preroll, "sim": dataclasses.asdict(self.sim)}


# --- clip checks -----------------------------------------------------------------------------------

def check_clip(clip) -> None:
    """Reject a clip that cannot be meant for a FLAME-layout head in metres (InputError)."""
    reach = float(np.abs(clip.translation).max(initial=0.0))
    if reach > MAX_TRANSLATION:
        raise InputError(f"the clip's translation reaches {reach:.4g} m: clips are in metres "
                         "(is this one in millimetres, or for another model?)")
    angle = float(np.linalg.norm(clip.pose.reshape(len(clip.pose), -1, 3), axis=2).max(initial=0.0))
    if angle > 4 * np.pi:
        raise InputError(f"the clip has a joint rotation of {np.degrees(angle):.0f} degrees: "
                         "axis-angle poses are in radians (is this clip in degrees?)")


def prepare_clip(clip, head_model, config: BakeConfig):
    """The clip as baked: checked, resampled, expressions fitted to the model (with an
    `ExprDimsWarning` if they do not fit) -> (clip, start, stop) with frames start..stop-1."""
    check_clip(clip)
    if config.fps is not None and abs(config.fps - clip.fps) > 1e-9 * clip.fps:
        clip = clip.resample(config.fps)
    e = head_model.num_expr
    if clip.expr_dims > e and not clip.expr[:, e:].any():
        clip = clip.replace(expr=clip.expr[:, :e])  # only zeros dropped: nothing to warn about
    elif clip.expr_dims == 0:
        clip = clip.replace(expr=np.zeros((clip.n_frames, e), np.float32))  # no expressions: neutral
    else:
        clip = clip.with_expr_dims(e)
    n = clip.n_frames
    if config.frames is None:
        return clip, 0, n
    start, stop = config.frames
    rng = range(n)[slice(start, stop)]
    if len(rng) == 0:
        raise InputError(f"frame range {start}:{'' if stop is None else stop} is empty: the clip has "
                         f"{n} frames{' at ' + format(clip.fps, 'g') + ' fps' if config.fps else ''}")
    return clip, rng.start, rng.stop


# --- the bake ---------------------------------------------------------------------------------------

class BakeFrames:
    """The lazy iterator of a bake's frames. `timings` accumulates seconds per stage (head LBS,
    bald Gaussians, hair simulation, hair deformation) over the frames produced so far."""

    def __init__(self, avatar, clip, start: int, stop: int, config: BakeConfig):
        self.avatar, self.clip, self.start, self.stop, self.config = avatar, clip, start, stop, config
        self.timings = {"head": 0.0, "bald": 0.0, "simulate": 0.0, "hair": 0.0}
        self.produced = 0
        self._gen = self._frames()

    def __len__(self) -> int:
        return self.stop - self.start

    def __iter__(self) -> "BakeFrames":
        return self

    def __next__(self) -> BakeFrame:
        return next(self._gen)

    def close(self) -> None:
        self._gen.close()

    def _frames(self) -> Iterator[BakeFrame]:
        from avatarkit.head.model import HeadParams

        avatar, clip, cfg = self.avatar, self.clip, self.config
        if not avatar.has_hair:
            yield from self._head_frames()
            return
        head = avatar.head_model
        binding = avatar.binding
        driver = avatar.hair_driver(cfg.sim)
        fps = float(clip.fps)
        dt = 1.0 / fps
        # a static cage has no history: start where the output starts
        first = self.start if cfg.sim.static else 0
        t = self.timings
        batch = cfg.hair_batch
        deformer = driver.deformer
        # chunks of `batch` frames: pose the head (LBS batched), step the cage through them, then
        # deform the hair of all of them in one product and yield the frames one by one; only
        # one chunk's arrays are alive at a time, whatever the clip's length
        for chunk in range(first, self.stop, batch):
            idx = np.arange(chunk, min(self.stop, chunk + batch))
            c0 = time.perf_counter()
            vertices = []
            transforms = []
            for s in range(0, len(idx), POSE_CHUNK):
                params = HeadParams(**{k: getattr(clip, k)[idx[s:s + POSE_CHUNK]] for k in
                                       ("expr", "rotation", "translation", "neck", "jaw", "eyes")},
                                    shape=avatar.shape)
                v, a = head.forward(params)
                vertices.append(v)
                transforms.append(a)  # every joint: collision follows the jaw and neck
            vertices = np.concatenate(vertices)
            transforms = np.concatenate(transforms).astype(np.float64)
            c1 = time.perf_counter()
            t["head"] += c1 - c0
            cages, head_frames = [], []
            for k, i in enumerate(idx):
                if i == first:
                    cage = driver.reset(vertices[k], transforms[k], warmup=cfg.preroll, dt=dt)
                else:
                    cage = driver.step(vertices[k], transforms[k], dt)
                if i >= self.start:
                    cages.append(np.ascontiguousarray(cage, np.float32))
                    head_frames.append(driver.frame)
            c2 = time.perf_counter()
            t["simulate"] += c2 - c1
            if not cages:
                continue
            lead = len(idx) - len(cages)  # frames before the output's start (ranged bakes)
            if batch == 1:
                hairs = (driver.hair_arrays(cages[0]),)
            else:
                hairs = ((driver.pushed_out(h[0], f), *h[1:]) for h, f in
                         zip(deformer.deform_batch(np.stack(cages), chunk=len(cages)), head_frames))
            for k, (cage, hair_arrays) in enumerate(zip(cages, hairs)):
                c3 = time.perf_counter()
                v = vertices[lead + k]
                face = SplatFrame(*binding_to_world(binding, v))
                c4 = time.perf_counter()
                hair = SplatFrame(*hair_arrays)
                t["bald"] += c4 - c3
                # the product runs when the first frame is drawn, the rebuild for each frame
                t["hair"] += c3 - c2
                out = int(idx[lead + k] - self.start)
                self.produced += 1
                yield BakeFrame(out, out / fps, np.ascontiguousarray(v, np.float32), face, hair, cage)
                c2 = time.perf_counter()


    def _head_frames(self) -> Iterator[BakeFrame]:
        """The frames of a hairless avatar: the posed head and its bald Gaussians only."""
        from avatarkit.head.model import HeadParams

        avatar, clip = self.avatar, self.clip
        binding = avatar.binding
        fps = float(clip.fps)
        t = self.timings
        no_hair = SplatFrame(np.zeros((0, 3), np.float32), np.zeros((0, 4), np.float32),
                             np.zeros((0, 3), np.float32))
        no_cage = np.zeros((0, 3), np.float32)
        for chunk in range(self.start, self.stop, POSE_CHUNK):
            idx = np.arange(chunk, min(self.stop, chunk + POSE_CHUNK))
            c0 = time.perf_counter()
            params = HeadParams(**{k: getattr(clip, k)[idx] for k in
                                   ("expr", "rotation", "translation", "neck", "jaw", "eyes")},
                                shape=avatar.shape)
            vertices = avatar.head_model.forward(params)[0]
            t["head"] += time.perf_counter() - c0
            for k, i in enumerate(idx):
                c1 = time.perf_counter()
                v = np.ascontiguousarray(vertices[k], np.float32)
                face = SplatFrame(*binding_to_world(binding, v))
                t["bald"] += time.perf_counter() - c1
                out = int(i - self.start)
                self.produced += 1
                yield BakeFrame(out, out / fps, v, face, no_hair, no_cage)


def with_avatar_defaults(config: BakeConfig, avatar) -> BakeConfig:
    """`config` with what it leaves to the avatar decided: `sim.static` None becomes True for an
    avatar built with short, rigid hair (`hair_mode == "rigid"`), False otherwise."""
    if config.sim.static is not None:
        return config
    static = avatar.hair_mode == "rigid"
    return dataclasses.replace(config, sim=config.sim.replace(static=static))


def bake(avatar, clip, config: BakeConfig | None = None) -> tuple[BakeStatic, BakeFrames]:
    """Bake `clip` (a `MotionClip`) on `avatar` -> (static data, lazy iterator of `BakeFrame`s).

    Everything that can fail on bad input (the clip, the range, the settings) is checked before
    this returns; the iterator only computes."""
    from avatarkit import __version__

    config = with_avatar_defaults(config or BakeConfig(), avatar)
    clip, start, stop = prepare_clip(clip, avatar.head_model, config)
    frames = BakeFrames(avatar, clip, start, stop, config)
    provenance = {
        "tool": "avatarkit", "version": __version__,
        "avatar": str(avatar.path) if avatar.path is not None else avatar.name,
        "head_model": avatar.head_ref.kind,
        "clip": clip.name, "clip_frames": int(clip.n_frames), "source_frames": [int(start), int(stop)],
        "fps": float(clip.fps), "settings": config.to_json(),
    }
    static = BakeStatic(fps=float(clip.fps), n_frames=int(stop - start),
                        head_faces=np.ascontiguousarray(avatar.head_model.faces, np.int32),
                        face=avatar.bald, hair=avatar.hair,
                        cage_faces=(np.ascontiguousarray(avatar.cage.faces, np.int32) if avatar.cage is not None
                                    else np.zeros((0, 3), np.int32)),
                        provenance=provenance)
    return static, frames


@dataclass
class BakeSummary:
    """What `run_bake` did: frames written, wall time, per-stage and per-writer seconds, and
    what each writer's close() returned."""

    frames: int
    seconds: float
    timings: dict[str, float]
    results: list[Any]

    @property
    def fps(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else float("inf")


def run_bake(avatar, clip, config: BakeConfig | None, writers: Sequence[Any],
             progress: Callable[[int, int], None] | None = None) -> BakeSummary:
    """Bake once and feed every frame to all `writers` (objects with begin/write/close/abort).

    On any exception (Ctrl-C included) every writer is aborted: nothing is left under the
    requested names. progress(done, total) is called after each frame."""
    t0 = time.perf_counter()
    static, frames = bake(avatar, clip, config)
    write_time = [0.0] * len(writers)
    started: list[Any] = []
    try:
        for w in writers:
            started.append(w)
            w.begin(static)
        total = len(frames)
        for done, frame in enumerate(frames, 1):
            for j, w in enumerate(writers):
                c = time.perf_counter()
                w.write(frame)
                write_time[j] += time.perf_counter() - c
            if progress is not None:
                progress(done, total)
        results = []
        for j, w in enumerate(writers):
            c = time.perf_counter()
            results.append(w.close())
            write_time[j] += time.perf_counter() - c
    except BaseException:
        # the writers first: nothing may stay half-written, even if closing the frames' generator
        # or a second signal (a batch worker's SIGTERM when its driver goes) raises meanwhile
        for w in started:
            try:
                w.abort()
            except BaseException:  # noqa: BLE001 -- keep aborting the others; the first error wins
                pass
        try:
            frames.close()
        except BaseException:  # noqa: BLE001 -- the error that stopped the bake is the one raised
            pass
        raise
    timings = dict(frames.timings)
    for w, s in zip(writers, write_time):
        timings[f"write {type(w).__name__}"] = s
    return BakeSummary(frames.produced, time.perf_counter() - t0, timings, results)


__all__ = ["BakeConfig", "BakeFrames", "BakeSummary", "MAX_TRANSLATION", "bake", "check_clip", "prepare_clip",
           "run_bake"]
