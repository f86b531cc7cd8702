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
# no `from __future__ import annotations`: Taichi evaluates the kernel's annotations
import dataclasses
import functools
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import numpy as np

from avatarkit.baked import BakeFrame, BakeStatic, SplatFrame
from avatarkit.errors import InputError, OutputError
from avatarkit.fileio import check_output_folder
from avatarkit.limits import MAX_FPS, MAX_PREROLL_SECONDS, MIN_FPS
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
    hair_batch: int = HAIR_BATCH

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


# --- bald Gaussians: triangle-local -> world (fast path) --------------------------------------------

@functools.cache
def _binding_kernel():
    """A fused Taichi kernel of `TriangleBinding.to_world` (means, quats, scales only)."""
    from avatarkit._taichi import ensure_taichi
    from avatarkit.rig.frames import MIN_EDGE, MIN_RELATIVE_HEIGHT

    ti = ensure_taichi()
    f64 = ti.f64

    @ti.kernel
    def to_world(verts: ti.types.ndarray(dtype=ti.f32, ndim=2), faces: ti.types.ndarray(dtype=ti.i32, ndim=2),
                 face_ids: ti.types.ndarray(dtype=ti.i32, ndim=1),
                 local_means: ti.types.ndarray(dtype=ti.f32, ndim=2),
                 local_quats: ti.types.ndarray(dtype=ti.f32, ndim=2),
                 local_scales: ti.types.ndarray(dtype=ti.f32, ndim=2),
                 means: ti.types.ndarray(dtype=ti.f32, ndim=2), quats: ti.types.ndarray(dtype=ti.f32, ndim=2),
                 scales: ti.types.ndarray(dtype=ti.f32, ndim=2), bad: ti.types.ndarray(dtype=ti.i32, ndim=1)):
        # float64 inside, like the reference (rig.frames / rig.binding)
        for i in range(face_ids.shape[0]):
            f = face_ids[i]
            a = ti.Vector([verts[faces[f, 0], 0], verts[faces[f, 0], 1], verts[faces[f, 0], 2]], dt=f64)
            b = ti.Vector([verts[faces[f, 1], 0], verts[faces[f, 1], 1], verts[faces[f, 1], 2]], dt=f64)
            c = ti.Vector([verts[faces[f, 2], 0], verts[faces[f, 2], 1], verts[faces[f, 2], 2]], dt=f64)
            d1 = b - a
            d2 = c - a
            len0 = d1.norm()
            e0 = d1 / ti.max(len0, MIN_EDGE)
            nraw = e0.cross(d2)
            height = nraw.norm()
            if len0 <= MIN_EDGE or height <= MIN_RELATIVE_HEIGHT * len0:
                bad[0] = f + 1
            n = nraw / ti.max(height, 1e-300)
            bb = e0.cross(n)
            k = 0.5 * (len0 + height)
            t = (a + b + c) / 3.0
            lm = ti.Vector([local_means[i, 0], local_means[i, 1], local_means[i, 2]], dt=f64)
            mu = k * (e0 * lm[0] + n * lm[1] + bb * lm[2]) + t
            # R = [e0 | n | bb] (columns) -> quaternion, Shepperd's method as rotations.matrix_to_quat
            m00, m01, m02 = e0[0], n[0], bb[0]
            m10, m11, m12 = e0[1], n[1], bb[1]
            m20, m21, m22 = e0[2], n[2], bb[2]
            tr = m00 + m11 + m22
            qw, qx, qy, qz = ti.f64(1.0), ti.f64(0.0), ti.f64(0.0), ti.f64(0.0)
            if tr >= m00 and tr >= m11 and tr >= m22:
                r = ti.sqrt(1.0 + tr) * 2.0
                qw, qx, qy, qz = 0.25 * r, (m21 - m12) / r, (m02 - m20) / r, (m10 - m01) / r
            elif m00 >= m11 and m00 >= m22:
                r = ti.sqrt(1.0 + m00 - m11 - m22) * 2.0
                qw, qx, qy, qz = (m21 - m12) / r, 0.25 * r, (m01 + m10) / r, (m02 + m20) / r
            elif m11 >= m22:
                r = ti.sqrt(1.0 + m11 - m00 - m22) * 2.0
                qw, qx, qy, qz = (m02 - m20) / r, (m01 + m10) / r, 0.25 * r, (m12 + m21) / r
            else:
                r = ti.sqrt(1.0 + m22 - m00 - m11) * 2.0
                qw, qx, qy, qz = (m10 - m01) / r, (m02 + m20) / r, (m12 + m21) / r, 0.25 * r
            if qw < 0:
                qw, qx, qy, qz = -qw, -qx, -qy, -qz
            lw, lx, ly, lz = (ti.cast(local_quats[i, 0], f64), ti.cast(local_quats[i, 1], f64),
                              ti.cast(local_quats[i, 2], f64), ti.cast(local_quats[i, 3], f64))
            w = qw * lw - qx * lx - qy * ly - qz * lz
            x = qw * lx + qx * lw + qy * lz - qz * ly
            y = qw * ly - qx * lz + qy * lw + qz * lx
            z = qw * lz + qx * ly - qy * lx + qz * lw
            norm = ti.sqrt(w * w + x * x + y * y + z * z)
            for j in ti.static(range(3)):
                means[i, j] = ti.cast(mu[j], ti.f32)
                scales[i, j] = ti.cast(k * local_scales[i, j], ti.f32)
            quats[i, 0] = ti.cast(w / norm, ti.f32)
            quats[i, 1] = ti.cast(x / norm, ti.f32)
            quats[i, 2] = ti.cast(y / norm, ti.f32)
            quats[i, 3] = ti.cast(z / norm, ti.f32)

    return to_world


def binding_to_world(binding, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fast `TriangleBinding.to_world` for one mesh pose: vertices (V, 3) -> means (N, 3),
    quats (N, 4) wxyz, scales (N, 3), float32. InputError if a host triangle collapsed."""
    v = np.ascontiguousarray(vertices, dtype=np.float32)
    if v.ndim != 2 or v.shape[1] != 3:
        raise InputError(f"vertices must have shape (V, 3), got {v.shape}")
    if not np.isfinite(v).all():
        raise InputError("vertices contain non-finite values")
    n = len(binding)
    means = np.empty((n, 3), np.float32)
    quats = np.empty((n, 4), np.float32)
    scales = np.empty((n, 3), np.float32)
    bad = np.zeros(1, np.int32)
    if n:
        local = binding.local
        _binding_kernel()(v, binding.faces, binding.face_ids, local.means, local.quats, local.scales,
                          means, quats, scales, bad)
    if bad[0]:
        raise InputError(f"triangle {int(bad[0]) - 1} collapsed (zero area); its Gaussians have no frame")
    return means, quats, scales


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
                transforms.append(a[:, driver.head_joint])
            vertices = np.concatenate(vertices)
            transforms = np.concatenate(transforms).astype(np.float64)
            c1 = time.perf_counter()
            t["head"] += c1 - c0
            cages = []
            for k, i in enumerate(idx):
                if i == first:
                    cage = driver.reset(vertices[k], transforms[k], warmup=cfg.preroll, dt=dt)
                else:
                    cage = driver.step(vertices[k], transforms[k], dt)
                if i >= self.start:
                    cages.append(np.ascontiguousarray(cage, np.float32))
            c2 = time.perf_counter()
            t["simulate"] += c2 - c1
            if not cages:
                continue
            lead = len(idx) - len(cages)  # frames before the output's start (ranged bakes)
            if batch == 1:
                hairs = (driver.hair_arrays(cages[0]),)
            else:
                hairs = deformer.deform_batch(np.stack(cages), chunk=len(cages))
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


# --- writers ---------------------------------------------------------------------------------------

class PreviewWriter:
    """Renders each baked frame (bald + hair) with the CPU splat renderer into an .mp4/.gif.

    The camera frames the head of the first frame (the mesh's bounds, with room for hair around
    it) from the front; with `orbit` it turns once around the head over the clip. Same shape as
    the other bake writers: `begin(static)`, `write(frame)`, `close()`, `abort()`."""

    def __init__(self, path: str | os.PathLike, size: int = 384, orbit: bool = False,
                 background=(1.0, 1.0, 1.0), elevation_deg: float = 5.0, margin: float = 1.3):
        from avatarkit.export.video import video_format

        self.path = Path(path)
        video_format(self.path)  # OutputError for anything but .mp4/.gif
        if int(size) != size or size < 16:
            raise InputError(f"preview size must be an integer >= 16 pixels, got {size!r}")
        self.size, self.orbit, self.background = int(size), bool(orbit), background
        self.elevation_deg, self.margin = float(elevation_deg), float(margin)
        self._video = None
        self._static: BakeStatic | None = None
        self._target = self._distance = None
        self.frames = 0

    def __enter__(self) -> "PreviewWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is not None:
            self.abort()
        elif self._video is not None:
            self.close()
        return False

    def begin(self, static: BakeStatic) -> None:
        from avatarkit.export.video import VideoWriter

        self._static = static
        self._video = VideoWriter(self.path, fps=static.fps)

    def camera(self, frame: BakeFrame):
        from avatarkit.render import Camera, framing

        if self._target is None:
            v = frame.head_vertices
            self._target, self._distance = framing((v.min(0), v.max(0)), 30.0, self.size, self.size,
                                                   self.margin)
        n = max(self._static.n_frames, 1)
        azimuth = 360.0 * frame.index / n if self.orbit else 0.0
        return Camera.orbit(self._target, azimuth, self.elevation_deg, self._distance, 30.0,
                            self.size, self.size)

    def write(self, frame: BakeFrame) -> None:
        from avatarkit.gaussians import GaussianSet
        from avatarkit.render import render

        if self._video is None:
            raise InputError("write() needs begin() first")
        s = self._static
        gs = GaussianSet.concat([frame.gaussians(s, "face").replace(extras={}),
                                 frame.gaussians(s, "hair").replace(extras={})])
        self._video.append(render(gs, self.camera(frame), self.background).rgb)
        self.frames += 1

    def close(self) -> Path:
        video, self._video = self._video, None
        if video is not None:
            video.close()
        return self.path

    def abort(self) -> None:
        video, self._video = self._video, None
        if video is not None:  # leaving its block with an exception deletes the partial file
            video.__exit__(RuntimeError, RuntimeError("bake aborted"), None)


WRITER_KINDS = ("usd", "ply", "preview")


def make_writer(kind: str, target: str | os.PathLike, options: dict | None = None):
    """The bake writer of one output kind: "usd" -> `UsdStageWriter` (options: the fields of
    `UsdWriteOptions`), "ply" -> `PlySequenceWriter` (split, ply_frame), "preview" -> `PreviewWriter`
    (size, orbit). Options left out take the writer's defaults."""
    options = dict(options or {})
    if kind == "usd":
        from avatarkit.export.usd_stage import UsdStageWriter, UsdWriteOptions

        return UsdStageWriter(target, UsdWriteOptions(**options))
    if kind == "ply":
        from avatarkit.export.ply_sequence import PlySequenceWriter

        return PlySequenceWriter(target, **options)
    if kind == "preview":
        return PreviewWriter(target, **options)
    raise InputError(f"unknown bake output kind {kind!r}; use one of {', '.join(WRITER_KINDS)}")


def check_output(kind: str, path: str | os.PathLike) -> Path:
    """Raise OutputError unless `path` can receive a bake output of `kind` (see `make_writer`):
    a known extension (usd, preview), not a folder (usd, preview) or not a file (ply), and a
    writable folder to go in. Cheap: meant to run before anything is loaded or baked."""
    p = Path(path)
    if kind == "ply":
        if p.exists() and not p.is_dir():
            raise OutputError("is a file, not a folder", p)
        check_output_folder(p if p.exists() else p.parent)
        return p
    if kind == "usd":
        from avatarkit.gaussians.usd import USD_EXTENSIONS as extensions
        what = "USD"
    elif kind == "preview":
        from avatarkit.export.video import VIDEO_EXTENSIONS as extensions
        what = "preview"
    else:
        raise InputError(f"unknown bake output kind {kind!r}; use one of {', '.join(WRITER_KINDS)}")
    if p.suffix.lower() not in extensions:
        raise OutputError(f"unknown {what} extension {p.suffix or '(none)'!r}; use one of "
                          f"{', '.join(extensions)}", p)
    if p.is_dir():
        raise OutputError("is a folder, not a file name", p)
    check_output_folder(p.parent)
    return p


def output_bytes(kind: str, path: str | os.PathLike) -> int:
    """Bytes on disk of a written output: its file or its folder's files, plus for "usd" the
    stage's `<name>_clips/` folder of value-clip layers (not for .usdz, which holds them)."""
    p = Path(path)
    size = _tree_bytes(p)
    clips = usd_clips_folder(p) if kind == "usd" else None
    return size + (_tree_bytes(clips) if clips is not None else 0)


def usd_clips_folder(path: str | os.PathLike) -> Path | None:
    """The `<name>_clips/` folder written beside a USD stage, if there is one."""
    from avatarkit.export.usd_stage import CLIP_FOLDER_SUFFIX

    p = Path(path)
    clips = p.parent / (p.stem + CLIP_FOLDER_SUFFIX)
    return clips if p.suffix.lower() != ".usdz" and clips.is_dir() else None


def _tree_bytes(path: Path) -> int:
    if path.is_dir():
        return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())
    return path.stat().st_size if path.exists() else 0



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
        frames.close()
        for w in started:
            try:
                w.abort()
            except Exception:  # noqa: BLE001 -- keep aborting the others; the first error wins
                pass
        raise
    timings = dict(frames.timings)
    for w, s in zip(writers, write_time):
        timings[f"write {type(w).__name__}"] = s
    return BakeSummary(frames.produced, time.perf_counter() - t0, timings, results)


__all__ = ["BakeConfig", "BakeFrames", "BakeSummary", "PreviewWriter", "WRITER_KINDS", "bake",
           "binding_to_world", "check_clip", "check_output", "make_writer", "output_bytes",
           "prepare_clip", "run_bake", "usd_clips_folder", "MAX_TRANSLATION"]
