"""PLY-sequence writer: files read back with plyfile, sidecar, atomic behaviour, inspection."""
from __future__ import annotations

import json

import numpy as np
import pytest
from plyfile import PlyData

from avatarkit.baked import BakeFrame, SplatFrame
from avatarkit.errors import FormatError, InputError, OutputError
from avatarkit.export.ply_sequence import PlySequenceWriter, read_sidecar, split_parts
from avatarkit.gaussians.ply import read_ply, write_ply
from avatarkit.gaussians.sh import SH_COUNTS
from avatarkit.inspect import inspect_file
from test_usd_stage import FPS, synthetic_bake


@pytest.fixture(scope="module")
def bake():
    return synthetic_bake(n_frames=6)


def write_sequence(folder, static, frames, split=False, ply_frame="yup"):
    with PlySequenceWriter(folder, split=split, ply_frame=ply_frame) as writer:
        writer.begin(static)
        for f in frames:
            writer.write(f)
    return writer


def _listing(folder):
    return sorted(p.name for p in folder.iterdir())


def _check_vertex(v, means, quats, scales, opacities, sh):
    """A plyfile vertex element against activated values (INRIA encoding)."""
    np.testing.assert_array_equal(np.stack([v["x"], v["y"], v["z"]], 1), means)
    np.testing.assert_array_equal(np.stack([v[f"rot_{i}"] for i in range(4)], 1), quats)
    np.testing.assert_allclose(np.exp(np.stack([v[f"scale_{i}"] for i in range(3)], 1)), scales, rtol=1e-6)
    np.testing.assert_allclose(1 / (1 + np.exp(-v["opacity"].astype(np.float64))), opacities, rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(np.stack([v[f"f_dc_{i}"] for i in range(3)], 1), sh[:, 0])
    k = sh.shape[1]
    rest = np.stack([v[f"f_rest_{i}"] for i in range(3 * (k - 1))], 1) if k > 1 else np.zeros((len(sh), 0))
    np.testing.assert_array_equal(rest.reshape(len(sh), 3, k - 1).transpose(0, 2, 1), sh[:, 1:])


def test_merged_frames_read_back_with_plyfile(tmp_path, bake):
    static, frames = bake
    folder = tmp_path / "seq"
    write_sequence(folder, static, frames)
    names = [f"frame_{i:05d}.ply" for i in range(len(frames))]
    assert _listing(folder) == sorted(names + ["sequence.json"])
    degree = max(static.face.sh_degree, static.hair.sh_degree)
    k = SH_COUNTS[degree]
    pad = np.zeros((len(static.hair), k - static.hair.sh.shape[1], 3), np.float32)
    sh = np.concatenate([static.face.sh, np.concatenate([static.hair.sh, pad], axis=1)])
    for f in frames:
        ply = PlyData.read(str(folder / f"frame_{f.index:05d}.ply"))
        v = ply["vertex"].data
        names_in_file = [p.name for p in ply["vertex"].properties]
        assert names_in_file[:6] == ["x", "y", "z", "nx", "ny", "nz"] and names_in_file[-1] == "part"
        # float32 like every other column: readers that map rows as float arrays need that
        assert {p.val_dtype for p in ply["vertex"].properties} <= {"f4", "float32"}
        assert not ply.text and ply.byte_order == "<"
        parts = (f.face, f.hair)
        _check_vertex(v, np.concatenate([p.means for p in parts]), np.concatenate([p.quats for p in parts]),
                      np.concatenate([p.scales for p in parts]),
                      np.concatenate([static.face.opacities, static.hair.opacities]), sh)
        np.testing.assert_array_equal(v["part"], np.repeat([0, 1], [len(static.face), len(static.hair)]))
        assert "binding" not in names_in_file
    doc = json.loads((folder / "sequence.json").read_text())
    assert doc["fps"] == FPS and doc["frame_count"] == len(frames) and doc["frames"] == list(range(len(frames)))
    assert doc["files"] == names and doc["split"] is False
    assert doc["parts"]["face"] == {"gaussians": len(static.face), "sh_degree": 3, "part": 0}
    assert doc["parts"]["hair"] == {"gaussians": len(static.hair), "sh_degree": 1, "part": 1}
    assert doc["provenance"]["clip"]["name"] == "turn"
    assert read_sidecar(folder) == doc


@pytest.mark.parametrize("dtype", [np.float32, np.uint8, np.int32])
def test_split_parts_reads_float_and_integer_part_columns(tmp_path, bake, dtype):
    """Merged frames hold `part` as float now and as uchar before: both split back exactly."""
    static, frames = bake
    folder = tmp_path / "seq"
    write_sequence(folder, static, frames[:2])
    gs = read_ply(folder / "frame_00001.ply")
    assert gs.extras["part"].dtype == np.float32
    old = tmp_path / "old.ply"  # the same frame as an older avatarkit wrote it
    write_ply(old, gs.replace(extras={"part": gs.extras["part"].astype(dtype)}))
    parts = split_parts(read_ply(old), old)
    assert list(parts) == ["face", "hair"]
    for name, moving in (("face", frames[1].face), ("hair", frames[1].hair)):
        np.testing.assert_array_equal(parts[name].means, moving.means)
        np.testing.assert_array_equal(parts[name].quats, moving.quats)
        assert parts[name].extras == {}
    np.testing.assert_array_equal(parts["face"].sh, static.face.sh)


def test_split_parts_rejects_other_values(tmp_path):
    from helpers import random_gaussians

    gs = random_gaussians(5)
    with pytest.raises(FormatError, match="x.ply: no 'part' property"):
        split_parts(gs, "x.ply")
    with pytest.raises(FormatError, match="'part' holds 0.5"):
        split_parts(gs.replace(extras={"part": np.array([0, 1, 0.5, 1, 0], np.float32)}), "x.ply")
    face_only = split_parts(gs.replace(extras={"part": np.zeros(5, np.float32)}))
    assert list(face_only) == ["face"] and len(face_only["face"]) == 5


def test_split_frames(tmp_path, bake):
    static, frames = bake
    folder = tmp_path / "seq"
    writer = PlySequenceWriter(folder, split=True)
    writer.begin(static)
    for f in frames:
        writer.write(f)
    result = writer.close()
    assert result.frames == len(frames) and result.files == 2 * len(frames)
    assert result.bytes == sum(p.stat().st_size for p in folder.glob("*.ply"))
    assert len(_listing(folder)) == 2 * len(frames) + 1
    for f in (frames[0], frames[-1]):
        for part, rest in (("face", static.face), ("hair", static.hair)):
            ply = PlyData.read(str(folder / f"{part}_{f.index:05d}.ply"))
            assert [p.name for p in ply["vertex"].properties][-1] == "rot_3"  # no extras
            moving = getattr(f, part)
            _check_vertex(ply["vertex"].data, moving.means, moving.quats, moving.scales, rest.opacities, rest.sh)
            gs = read_ply(folder / f"{part}_{f.index:05d}.ply")  # our reader agrees
            np.testing.assert_array_equal(gs.means, moving.means)
    doc = read_sidecar(folder / "sequence.json")
    assert doc["split"] is True
    assert doc["files"]["hair"] == [f"hair_{i:05d}.ply" for i in range(len(frames))]


def test_failure_leaves_the_folder_as_it_was(tmp_path, bake):
    static, frames = bake
    folder = tmp_path / "seq"
    write_sequence(folder, static, frames[:3])
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    later = [BakeFrame(f.index, f.time, f.head_vertices, SplatFrame(f.face.means + np.float32(1), f.face.quats,
                                                                    f.face.scales), f.hair, f.cage_vertices)
             for f in frames]
    with pytest.raises(KeyboardInterrupt):
        with PlySequenceWriter(folder) as writer:
            writer.begin(static)
            for f in later:
                writer.write(f)
                if f.index == 4:
                    raise KeyboardInterrupt
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before
    # a folder the writer made itself is removed again
    fresh = tmp_path / "new" / "seq"
    writer = PlySequenceWriter(fresh)
    writer.begin(static)
    writer.write(frames[0])
    writer.abort()
    assert not fresh.exists()


def test_rewrite_removes_stale_frames_only(tmp_path, bake):
    static, frames = bake
    folder = tmp_path / "seq"
    write_sequence(folder, static, frames)
    (folder / "notes.txt").write_text("mine")
    (folder / "frame_99999.ply").write_text("not listed by the sidecar")
    write_sequence(folder, static, frames[:2], split=True)
    assert _listing(folder) == ["face_00000.ply", "face_00001.ply", "frame_99999.ply", "hair_00000.ply",
                                "hair_00001.ply", "notes.txt", "sequence.json"]


def test_errors(tmp_path, bake):
    static, frames = bake
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(OutputError, match="is a file"):
        PlySequenceWriter(blocker).begin(static)
    with pytest.raises(OutputError, match="cannot write"):
        PlySequenceWriter(blocker / "seq").begin(static)
    folder = tmp_path / "seq"
    short = BakeFrame(2, 0.0, frames[2].head_vertices, frames[2].face,
                      SplatFrame(frames[2].hair.means[:-1], frames[2].hair.quats[:-1], frames[2].hair.scales[:-1]),
                      frames[2].cage_vertices)
    bad_scale = BakeFrame(2, 0.0, frames[2].head_vertices, SplatFrame(frames[2].face.means, frames[2].face.quats,
                                                                      -frames[2].face.scales),
                          frames[2].hair, frames[2].cage_vertices)
    for split in (False, True):
        for bad, message in ((short, "frame 2: hair has 89 Gaussians but the bake.s static data has 90"),
                             (bad_scale, "frame 2: scales must be > 0"),
                             (frames[0], "increasing index order")):
            with pytest.raises(InputError, match=message):
                write_sequence(folder, static, [frames[0], frames[1], bad], split=split)
            assert not folder.exists()
    with pytest.raises(InputError, match="no frames"):
        write_sequence(folder, static, [])
    assert not folder.exists()
    with pytest.raises(InputError, match="begin"):
        PlySequenceWriter(folder).write(frames[0])


def test_inspect_sequence(tmp_path, bake):
    static, frames = bake
    folder = tmp_path / "seq"
    write_sequence(folder, static, frames)
    for target in (folder, folder / "sequence.json"):
        s = inspect_file(target)
        assert s.kind == "PLY sequence"
        assert s.get("frames") == len(frames) and s.get("fps") == FPS
        assert s.get("frame range") == [0, len(frames) - 1]
        assert s.get("missing files") == "none"
        assert s.get("total size") == sum(p.stat().st_size for p in folder.glob("*.ply"))
        assert s.get("first frame") == [f"frame_00000.ply: {len(static.face) + len(static.hair):,} Gaussians"]
        assert [p["gaussians"] for p in s.get("parts")] == [len(static.face), len(static.hair)]
        json.dumps(s.to_dict())
    (folder / "frame_00003.ply").unlink()
    assert inspect_file(folder).get("missing files") == ["frame_00003.ply"]
    (folder / "sequence.json").write_text("{not json")
    with pytest.raises(FormatError, match="sequence.json: not valid JSON"):
        inspect_file(folder)
    (folder / "sequence.json").write_text(json.dumps({"format": "avatarkit.ply-sequence", "version": 1,
                                                      "fps": 24, "frame_count": 2, "frames": [0, 1],
                                                      "split": False, "parts": {}, "files": ["a.ply"]}))
    with pytest.raises(FormatError, match="'files' must list 2"):
        inspect_file(folder)
