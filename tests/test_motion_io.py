"""Motion clip files: GaussianAvatars/VHAP npz, per-frame folders, our JSON; bad input."""
from __future__ import annotations

import json

import numpy as np
import pytest

from avatarkit.errors import FormatError, InputError, OutputError
from avatarkit.motion import MotionClip, load_clip, save_clip
from avatarkit.schemas import load_schema, validate

CHANNELS = ("rotation", "translation", "neck", "jaw", "eyes", "expr")


def random_clip(n=12, fps=30.0, expr_dims=8, shape_dims=20, seed=0, name="clip") -> MotionClip:
    rng = np.random.default_rng(seed)
    r = lambda w, s=0.3: rng.normal(scale=s, size=(n, w))  # noqa: E731
    return MotionClip(fps, r(3), r(3, 0.01), r(3, 0.05), r(3, 0.1), r(6, 0.1), r(expr_dims, 1.0),
                      rng.normal(size=shape_dims), name=name)


def assert_same_clip(a: MotionClip, b: MotionClip):
    assert a.fps == b.fps and a.name == b.name
    for key in CHANNELS + ("shape",):
        np.testing.assert_array_equal(getattr(a, key), getattr(b, key), err_msg=key)


def vhap_arrays(clip: MotionClip) -> dict:
    """The whole-sequence layout VHAP's tracker writes (tracked_flame_params_*.npz), with extras."""
    n = clip.n_frames
    return {"rotation": clip.rotation, "translation": clip.translation, "neck_pose": clip.neck,
            "jaw_pose": clip.jaw, "eyes_pose": clip.eyes, "expr": clip.expr, "shape": clip.shape,
            "static_offset": np.zeros((1, 50, 3), np.float32), "focal_length": np.array([1.5]),
            "timestep_id": np.array([f"{i:05d}" for i in range(n)])}


# --- npz ---------------------------------------------------------------------------------------
def test_npz_round_trip(tmp_path):
    c = random_clip()
    save_clip(tmp_path / "c.npz", c)
    assert_same_clip(load_clip(tmp_path / "c.npz"), c)
    with np.load(tmp_path / "c.npz") as data:  # what other tools see
        assert {"rotation", "translation", "neck_pose", "jaw_pose", "eyes_pose", "expr", "shape",
                "fps"} <= set(data.files)
        assert data["eyes_pose"].shape == (12, 6) and data["eyes_pose"].dtype == np.float32
        assert data["shape"].shape == (20,)


def test_reads_vhap_sequence_with_default_fps(tmp_path):
    c = random_clip(fps=25.0, name="tracked_flame_params_30")
    np.savez(tmp_path / "tracked_flame_params_30.npz", **vhap_arrays(c))
    got = load_clip(tmp_path / "tracked_flame_params_30.npz")
    assert got.fps == 25.0  # VHAP's default when the file has none
    assert_same_clip(got, c)
    assert load_clip(tmp_path / "tracked_flame_params_30.npz", fps=50).fps == 50.0


@pytest.mark.parametrize("shape_layout", ["S", "1S", "TS"])
def test_singleton_axes_and_shape_layouts(tmp_path, shape_layout):
    c = random_clip(n=5)
    shape = {"S": c.shape, "1S": c.shape[None], "TS": np.tile(c.shape, (5, 1))}[shape_layout]
    np.savez(tmp_path / "m.npz", rotation=c.rotation[:, None], translation=c.translation[:, None],
             neck_pose=c.neck[:, None], jaw_pose=c.jaw[:, None], eyes_pose=c.eyes.reshape(5, 2, 3),
             expr=c.expr[:, None], shape=shape, fps=np.array(30.0))
    got = load_clip(tmp_path / "m.npz")
    assert_same_clip(got, c.replace(name="m"))


def test_float64_and_alias_keys(tmp_path):
    c = random_clip(n=4)
    np.savez(tmp_path / "a.npz", rotation=c.rotation.astype(np.float64), translation=c.translation,
             neck=c.neck, jaw=c.jaw, eyes=c.eyes, expr=c.expr)
    got = load_clip(tmp_path / "a.npz")
    np.testing.assert_array_equal(got.jaw, c.jaw)
    assert got.shape.shape == (0,)  # no shape key: keep the avatar's own


# --- per-frame folders -------------------------------------------------------------------------
def write_flame_param_folder(folder, clip: MotionClip, names=None):
    """VHAP export_as_nerf_dataset: one npz per timestep with (1, .) arrays and the static shape."""
    folder.mkdir(parents=True)
    names = names or [f"{i:05d}.npz" for i in range(clip.n_frames)]
    for i, name in enumerate(names):
        np.savez(folder / name, translation=clip.translation[[i]], rotation=clip.rotation[[i]],
                 neck_pose=clip.neck[[i]], jaw_pose=clip.jaw[[i]], eyes_pose=clip.eyes[[i]],
                 shape=clip.shape, expr=clip.expr[[i]], static_offset=np.zeros((1, 5, 3)))


def test_reads_vhap_export_folder(tmp_path):
    c = random_clip(n=6, fps=25.0)
    write_flame_param_folder(tmp_path / "export" / "flame_param", c)
    (tmp_path / "export" / "canonical_flame_param.npz").write_bytes(b"not read")
    for path in (tmp_path / "export", tmp_path / "export" / "flame_param"):
        got = load_clip(path)
        for key in CHANNELS + ("shape",):
            np.testing.assert_array_equal(getattr(got, key), getattr(c, key))
        assert got.fps == 25.0


def test_folder_is_read_in_natural_order(tmp_path):
    c = random_clip(n=11)
    names = [f"frame_{i}.npz" for i in range(11)]  # frame_10 sorts before frame_2 as text
    write_flame_param_folder(tmp_path / "frames", c, names)
    np.testing.assert_array_equal(load_clip(tmp_path / "frames", fps=30).rotation, c.rotation)


def test_folder_errors_name_the_file(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(FormatError, match="empty: folder holds no per-frame"):
        load_clip(tmp_path / "empty")
    c = random_clip(n=3)
    write_flame_param_folder(tmp_path / "f", c)
    np.savez(tmp_path / "f" / "00001.npz", rotation=np.zeros((1, 3)))
    with pytest.raises(FormatError, match=r"00001\.npz: missing keys translation"):
        load_clip(tmp_path / "f")


# --- json --------------------------------------------------------------------------------------
def test_json_round_trip_and_schema(tmp_path):
    c = random_clip(n=7, expr_dims=5, name="hello")
    save_clip(tmp_path / "c.json", c)
    doc = json.loads((tmp_path / "c.json").read_text())
    validate(doc, "motion")  # passes the published schema
    assert doc["format"] == "avatarkit.motion" and doc["version"] == 1
    assert len(doc["frames"]["eyes"]) == 7 and len(doc["frames"]["eyes"][0]) == 6
    assert_same_clip(load_clip(tmp_path / "c.json"), c)  # float32 values exactly


def test_json_with_zero_expr_and_shape(tmp_path):
    c = MotionClip.rest(3, 24.0, expr_dims=0, name="r")
    save_clip(tmp_path / "r.json", c)
    assert_same_clip(load_clip(tmp_path / "r.json"), c)


def test_npz_to_json_to_npz(tmp_path):
    c = random_clip()
    save_clip(tmp_path / "a.npz", c)
    save_clip(tmp_path / "b.json", load_clip(tmp_path / "a.npz"))
    save_clip(tmp_path / "c.npz", load_clip(tmp_path / "b.json"))
    assert_same_clip(load_clip(tmp_path / "c.npz"), c)


def test_schema_is_a_valid_draft_2020_12_schema():
    import jsonschema

    schema = load_schema("motion")
    jsonschema.Draft202012Validator.check_schema(schema)
    assert schema["properties"]["format"]["const"] == "avatarkit.motion"


def _json_doc(**frames_change):
    frames = {"rotation": [[0, 0, 0]] * 2, "translation": [[0, 0, 0]] * 2, "neck": [[0, 0, 0]] * 2,
              "jaw": [[0, 0, 0]] * 2, "eyes": [[0] * 6] * 2, "expr": [[0.5], [0.25]]}
    frames.update(frames_change)
    return {"format": "avatarkit.motion", "version": 1, "fps": 25, "frames": frames}


@pytest.mark.parametrize("doc, match", [
    (_json_doc(jaw=[[0, 0]] * 2), r"schema at \$\.frames\.jaw\[\d\]: \[0, 0\] is too short"),
    (_json_doc(jaw=[[0, 0, 0]]), "different frame counts"),
    (_json_doc(expr=[[0.5], [0.25, 1]]), "rows have different lengths"),
    ({**_json_doc(), "version": 7}, "version 7 is newer"),
    ({k: v for k, v in _json_doc().items() if k != "fps"}, "'fps' is a required property"),
    ({**_json_doc(), "fps": -1}, r"schema at \$\.fps"),
])
def test_bad_json_is_a_format_error_naming_the_file(tmp_path, doc, match):
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(doc))
    with pytest.raises(FormatError, match=match) as e:
        load_clip(p)
    assert str(e.value).startswith(str(p))


def test_json_nan_is_caught(tmp_path):
    p = tmp_path / "nan.json"
    p.write_text(json.dumps(_json_doc(rotation=[[0, float("nan"), 0], [0, 0, 0]])))
    with pytest.raises(FormatError, match="nan.json: 'frames.rotation' has a non-finite value at frame 0"):
        load_clip(p)


def test_not_json(tmp_path):
    p = tmp_path / "x.json"
    p.write_text("{nope")
    with pytest.raises(FormatError, match="x.json: not valid JSON"):
        load_clip(p)


# --- bad npz input -----------------------------------------------------------------------------
def _npz(tmp_path, **change):
    arrays = {k: v for k, v in vhap_arrays(random_clip(n=6)).items()}
    arrays.update(change)
    arrays = {k: v for k, v in arrays.items() if v is not None}
    np.savez(tmp_path / "bad.npz", **arrays)
    return tmp_path / "bad.npz"


@pytest.mark.parametrize("change, match", [
    ({"jaw_pose": None}, "missing key jaw_pose"),
    ({"jaw_pose": None, "expr": None}, "missing keys jaw_pose, expr"),
    ({"eyes_pose": np.zeros((6, 3))}, r"'eyes_pose' must have shape \(T, 6\), got \(6, 3\)"),
    ({"neck_pose": np.zeros((5, 3))}, r"different frame counts \(.*neck_pose 5"),
    ({"expr": np.full((6, 4), np.nan)}, "'expr' has a non-finite value at frame 0"),
    ({"shape": np.zeros((2, 2, 2))}, "'shape' must have shape"),
    ({"fps": np.array(-3.0)}, "fps must be a positive number"),
    ({"rotation": np.array(["a", "b"])}, "key 'rotation' holds"),
])
def test_bad_npz_is_a_format_error_naming_the_file(tmp_path, change, match):
    p = _npz(tmp_path, **change)
    with pytest.raises(FormatError, match=match) as e:
        load_clip(p)
    assert str(e.value).startswith(str(p))


def test_corrupt_and_missing_files(tmp_path):
    (tmp_path / "junk.npz").write_bytes(b"\x00" * 100)
    with pytest.raises(FormatError, match="junk.npz: not a readable .npz"):
        load_clip(tmp_path / "junk.npz")
    with pytest.raises(InputError, match="nothing.npz: no such file"):
        load_clip(tmp_path / "nothing.npz")
    (tmp_path / "clip.bvh").write_text("HIERARCHY")
    with pytest.raises(FormatError, match="unknown motion clip format '.bvh'"):
        load_clip(tmp_path / "clip.bvh")


def test_save_errors_and_atomicity(tmp_path):
    c = random_clip()
    with pytest.raises(OutputError, match="cannot write a motion clip as '.txt'"):
        save_clip(tmp_path / "c.txt", c)
    with pytest.raises(OutputError, match="does not exist"):
        save_clip(tmp_path / "no" / "such" / "c.npz", c)
    assert list(tmp_path.iterdir()) == []  # nothing half-written
