"""Every writer, failing part-way through a write (a full disk): an AvatarKitError (exit 2 at the
CLI) naming the requested output, and nothing left under the requested name nor any temporary
entry beside it. Each writer first runs once without the fault (so it does write enough bytes to
be cut, and Taichi's kernel cache is warm), then again into a fresh folder with every file capped
at LIMIT bytes (`faults.disk_full_after`)."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Callable

import numpy as np
import pytest

from avatarkit.errors import AvatarKitError
from faults import disk_full_after, entries
from helpers import random_gaussians
from test_avatar import small_avatar

#: bytes each file may take before writes fail: enough for headers, less than any output's body
LIMIT = 256

GS = random_gaussians(400, sh_degree=1, seed=4)


def _bake(writers_of: Callable[[Path], list], frames: int = 4):
    """A writer factory for a short bake on the small avatar, into the writers `writers_of(folder)`."""
    def write(folder: Path) -> None:
        from avatarkit.bake import BakeConfig, run_bake
        from avatarkit.motion import make_clip
        from avatarkit.sim.config import SimConfig

        clip = make_clip("shake", frames=frames, fps=25)
        config = BakeConfig(sim=SimConfig(substeps=1, iterations=2), preroll=0.0)
        run_bake(small_avatar(), clip, config, writers_of(folder))
    return write


def _usd_stage(chunk_frames):
    def writers(folder):
        from avatarkit.bake_writers import make_writer
        return [make_writer("usd", folder / "out.usdc", {"chunk_frames": chunk_frames})]
    return writers


def _ply_sequence(folder):
    from avatarkit.bake_writers import make_writer
    return [make_writer("ply", folder / "out_ply", {"split": False})]


def _gif_preview(folder):
    from avatarkit.bake_writers import make_writer
    return [make_writer("preview", folder / "out.gif", {"size": 32})]


def _convert_sequence(folder: Path) -> None:
    from avatarkit.convert import convert
    from avatarkit.gaussians.ply import write_ply

    src = folder.parent / f"{folder.name}_src"
    src.mkdir(exist_ok=True)
    for i in range(3):  # inputs are written before the fault: only the output is cut
        if not (src / f"f{i}.ply").exists():
            with disk_full_after(1 << 40):
                write_ply(src / f"f{i}.ply", GS)
    convert(src, folder / "out.usdc")


def _motion(ext):
    def write(folder):
        from avatarkit.motion import make_clip, save_clip
        save_clip(folder / f"out{ext}", make_clip("talk", frames=20, fps=25))
    return write


def _camera(folder):
    from avatarkit.render.camera import Camera
    Camera.orbit((0, 0, 0), 30.0, 10.0, 1.0, 30.0, 64, 64).to_json(folder / "out.camera.json")


def _png(folder):
    from avatarkit.export.images import write_png
    write_png(folder / "out.png", np.random.default_rng(0).uniform(size=(64, 64, 3)))


def _gif(folder):
    from avatarkit.export.video import write_video
    rng = np.random.default_rng(1)
    write_video(folder / "out.gif", (rng.uniform(size=(32, 32, 3)) for _ in range(3)), fps=10)


def _jpeg(folder):
    from avatarkit.recon.image_io import write_image
    write_image(folder / "out.jpg", np.random.default_rng(0).integers(0, 256, (64, 64, 3), dtype=np.uint8))


def _cage(folder):
    from avatarkit.cage.mesh import save_cage
    save_cage(folder / "out.ply", small_avatar().cage)


def _cage_weights(folder):
    from avatarkit.cage.deform import save_weights
    deformer = small_avatar().rig.deformer
    deformer.ensure_weights()
    save_weights(folder / "out.npz", deformer)


def _head_mesh(folder):
    from avatarkit.head.mesh_export import write_mesh
    write_mesh(small_avatar().head_model, folder / "out.obj")


def _head_model(folder):
    from avatarkit.head import save_npz
    save_npz(small_avatar().head_model, folder / "out.npz")


def _avatar(folder):
    small_avatar().save(folder / "out", preview=True)


def _batch_report(folder):
    from avatarkit.batch.job import JobResult
    from avatarkit.batch.runner import BatchReport

    jobs = [JobResult(f"a/clip{i}", "done", "a", f"clip{i}.npz") for i in range(20)]
    BatchReport(jobs, str(folder), "inline", 1, 0, 1.0, "2026-01-01T00:00:00Z").save(folder / "out.json")


def _batch_record(folder):
    from avatarkit.batch.records import write_record

    write_record(folder / "out.usdc", "usd", "k" * 64, "a/clip", {"avatar": {"path": "a" * 600}}, {}, 1.0)


#: name -> (write(folder), the names it must not leave behind when it fails)
WRITERS = {
    "ply": (lambda f: __import__("avatarkit.gaussians.ply", fromlist=["x"]).write_ply(f / "out.ply", GS),
            ["out.ply"]),
    "spz": (lambda f: __import__("avatarkit.gaussians.spz", fromlist=["x"]).write_spz(f / "out.spz", GS),
            ["out.spz"]),
    "usd-splats-usdc": (lambda f: __import__("avatarkit.gaussians.usd", fromlist=["x"]).save_usd(f / "out.usdc", GS),
                        ["out.usdc"]),
    "usd-splats-usda": (lambda f: __import__("avatarkit.gaussians.usd", fromlist=["x"]).save_usd(f / "out.usda", GS),
                        ["out.usda"]),
    "usd-splats-usdz": (lambda f: __import__("avatarkit.gaussians.usd", fromlist=["x"]).save_usd(f / "out.usdz", GS),
                        ["out.usdz"]),
    "usd-sequence": (_convert_sequence, ["out.usdc"]),
    "usd-stage": (_bake(_usd_stage(0)), ["out.usdc"]),
    "usd-stage-chunked": (_bake(_usd_stage(2)), ["out.usdc", "out_clips"]),
    "ply-sequence": (_bake(_ply_sequence), ["out_ply"]),
    "gif-preview": (_bake(_gif_preview), ["out.gif"]),
    "motion-npz": (_motion(".npz"), ["out.npz"]),
    "motion-json": (_motion(".json"), ["out.json"]),
    "camera-json": (_camera, ["out.camera.json"]),
    "png": (_png, ["out.png"]),
    "gif": (_gif, ["out.gif"]),
    "jpeg": (_jpeg, ["out.jpg"]),
    "cage": (_cage, ["out.ply"]),
    "cage-weights": (_cage_weights, ["out.npz"]),
    "head-mesh": (_head_mesh, ["out.obj"]),
    "head-model": (_head_model, ["out.npz"]),
    "avatar-folder": (_avatar, ["out"]),
    "batch-report": (_batch_report, ["out.json"]),
    "batch-record": (_batch_record, ["out.usdc.job.json"]),
}


@pytest.mark.parametrize("name", sorted(WRITERS))
def test_a_write_that_fails_midway_leaves_nothing(name, tmp_path):
    write, outputs = WRITERS[name]
    ok, cut = tmp_path / "ok", tmp_path / "cut"
    for f in (ok, cut):
        f.mkdir()
        if name == "batch-record":
            (f / "out.usdc").write_bytes(b"stage")  # the output the record vouches for
    write(ok)  # without the fault: it writes, and more than LIMIT bytes
    biggest = max(p.stat().st_size for p in ok.rglob("*") if p.is_file())
    assert biggest > LIMIT, f"{name} wrote only {biggest} bytes per file: the fault would not bite"
    before = entries(cut)
    with disk_full_after(LIMIT):
        with pytest.raises(AvatarKitError) as info:
            write(cut)
    message = str(info.value)
    assert "\n" not in message
    assert any(o in message for o in outputs) or str(cut) in message, message
    left = entries(cut)
    for o in outputs:
        assert o not in left, (name, left)
    assert left == before, (name, left)


def test_fault_helper_cuts_a_plain_write(tmp_path):
    """The helper itself: a Python write past the cap fails with OSError after the first bytes."""
    with disk_full_after(100):
        with open(tmp_path / "f", "wb", buffering=0) as fh, pytest.raises(OSError):
            fh.write(b"x" * 100)
            fh.write(b"x" * 900)
    assert 0 < (tmp_path / "f").stat().st_size <= 100
    json.dumps({})  # the cap is lifted again: large writes work
    (tmp_path / "g").write_bytes(b"y" * 10_000)
