"""Batch files: expansion, merging, templates, and every way a batch file can be wrong (a
FormatError naming the file and the job); input hashes and output records. No baking here."""
from __future__ import annotations

import dataclasses
import inspect
import json
from pathlib import Path

import pytest

from avatarkit.batch import records
from avatarkit.batch.spec import DEFAULT_OPTIONS, DEFAULT_OUTPUTS, load_batch, parse_batch
from avatarkit.errors import FormatError, InputError


def _write(path: Path, doc) -> Path:
    path.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    return path


@pytest.fixture
def tree(tmp_path):
    """avatars/{alice,bob} (placeholder files), clips/ with two clip files, a per-frame folder,
    a hidden file and an unrelated file."""
    for name in ("alice", "bob"):
        (tmp_path / "avatars" / name).mkdir(parents=True)
        (tmp_path / "avatars" / name / "avatar.json").write_text("{}")
    clips = tmp_path / "clips"
    clips.mkdir()
    for name in ("talk.json", "nod.npz", ".hidden.npz", "notes.txt"):
        (clips / name).write_bytes(b"x")
    (clips / "vhap_seq" / "flame_param").mkdir(parents=True)
    (clips / "vhap_seq" / "flame_param" / "00000.npz").write_bytes(b"y")
    (clips / "empty_dir").mkdir()
    return tmp_path


def test_expansion_merging_and_templates(tree):
    doc = {
        "format": "avatarkit.batch", "version": 1,
        "defaults": {"outputs": {"ply": "{name}_ply"}, "sim": {"substeps": 2, "gravity": [0, -5, 0]},
                     "preroll": 0.5, "usd": {"half": True}},
        "jobs": [
            {"avatar": ["avatars/alice", "avatars/bob"], "clips": "clips"},
            {"avatar": "avatars/bob", "clip": "clips/nod.npz", "name": "{avatar}/{clip}_static",
             "sim": {"static": True}, "frames": "1:3", "fps": 30,
             "outputs": {"ply": None, "preview": "previews/{avatar}_{clip}.gif"}, "preview": {"size": 64}},
        ],
    }
    batch = parse_batch(doc, base=tree, path=tree / "b.json")
    names = [j.name for j in batch.jobs]
    # avatar-major, clips in natural order, hidden/unrelated/empty entries ignored
    assert names == ["alice/nod", "alice/talk", "alice/vhap_seq", "bob/nod", "bob/talk", "bob/vhap_seq",
                     "bob/nod_static"]
    first = batch.jobs[0]
    assert first.avatar == tree / "avatars" / "alice" and first.clip == tree / "clips" / "nod.npz"
    assert [(o.kind, o.path) for o in first.outputs] == [("usd", "alice/nod.usdc"), ("ply", "alice/nod_ply")]
    assert first.output("usd").options == {**DEFAULT_OPTIONS["usd"], "half": True}
    # sim merges key by key over SimConfig's defaults; the job's own keys win
    assert first.config.sim.substeps == 2 and first.config.sim.gravity == (0.0, -5.0, 0.0)
    assert first.config.sim.iterations == 1 and not first.config.sim.static  # the default
    assert first.config.preroll == 0.5 and first.config.frames is None
    last = batch.jobs[-1]
    assert last.config.sim.static and last.config.sim.substeps == 2
    assert last.config.frames == (1, 3) and last.config.fps == 30
    assert [(o.kind, o.path) for o in last.outputs] == [("usd", "bob/nod_static.usdc"),
                                                        ("preview", "previews/bob_nod.gif")]
    assert last.output("preview").options == {"size": 64, "orbit": False}


def test_load_batch_resolves_against_the_files_folder(tree, monkeypatch):
    path = _write(tree / "b.json", {"jobs": [{"avatar": "avatars/alice", "clip": ["clips/nod.npz"]}]})
    monkeypatch.chdir(tree / "clips")  # the working folder does not matter
    batch = load_batch(path)
    assert len(batch) == 1 and batch.path == path
    assert batch.jobs[0].avatar == tree / "avatars" / "alice"
    assert [(o.kind, o.path) for o in batch.jobs[0].outputs] == [("usd", "alice/nod.usdc")]
    assert DEFAULT_OUTPUTS["usd"] == "{name}.usdc"


@pytest.mark.parametrize("doc, words", [
    ("{not json", ["not valid JSON", "line 1"]),
    ({"jobs": []}, ["jobs"]),
    ({"jobs": [{"avatar": "a"}]}, ["jobs[0]", "exactly one of 'clip'"]),
    ({"jobs": [{"avatar": "a", "clip": "c.npz", "clips": "clips"}]}, ["jobs[0]", "exactly one"]),
    ({"jobs": [{"avatar": "a", "clip": "c.npz", "colour": 1}]}, ["colour"]),
    ({"jobs": [{"avatar": "a", "clip": "c.npz", "sim": {"substeps": 0}}]}, ["substeps"]),
    ({"jobs": [{"avatar": "a", "clip": "c.npz", "sim": {"collision": "magic"}}]}, ["collision"]),
    ({"jobs": [{"avatar": "a", "clip": "c.npz", "outputs": {"usd": "x.abc"}}]}, ["outputs"]),
    ({"jobs": [{"avatar": "a", "clip": "c.npz", "frames": "abc"}]}, ["frames"]),
    ({"jobs": [{"avatar": "a", "clip": "c.npz", "frames": "5:5"}]}, None),  # empty, but only the clip knows
    ({"jobs": [{"avatar": "a", "clip": "c.npz", "outputs": {"usd": "../{clip}.usdc"}}]},
     ["jobs[0]", "inside the output folder"]),
    ({"jobs": [{"avatar": "a", "clip": "c.npz", "outputs": {"usd": "/abs/{clip}.usdc"}}]},
     ["relative to the output folder"]),
    ({"jobs": [{"avatar": "a", "clip": "c.npz", "outputs": {"usd": "{who}.usdc"}}]},
     ["unknown placeholder {who}"]),
    ({"jobs": [{"avatar": "a", "clip": "c.npz", "outputs": {"usd": None}}]}, ["no outputs"]),
    ({"jobs": [{"avatar": "a", "clip": "c.npz"}, {"avatar": "x/a", "clip": "c.json"}]},
     ["two jobs are named 'a/c'"]),
    ({"jobs": [{"avatar": "a", "clip": "c.npz"},
               {"avatar": "a", "clip": "c.npz", "name": "other", "outputs": {"usd": "a/c.usdc"}}]},
     ["both write a/c.usdc"]),
    ({"jobs": [{"avatar": "a", "clip": "c.npz", "outputs": {"ply": "{name}.usdc"}}]}, ["usd and ply"]),
    ({"jobs": [{"avatar": "a", "clips": "no_such_folder"}]}, ["jobs[0]", "not found"]),
    ({"jobs": [{"avatar": "a", "clips": "clips/empty_dir"}]}, ["holds no clips"]),
    ({"format": "avatarkit.avatar", "jobs": [{"avatar": "a", "clip": "c.npz"}]}, ["format"]),
])
def test_bad_batch_files(tree, doc, words):
    path = _write(tree / "bad.json", doc)
    if words is None:
        load_batch(path)
        return
    with pytest.raises(FormatError) as e:
        load_batch(path)
    assert str(e.value).startswith(f"{path}: "), str(e.value)
    for w in words:
        assert w in str(e.value), str(e.value)


def test_missing_or_unreadable_batch_file(tmp_path):
    with pytest.raises(InputError, match="not found"):
        load_batch(tmp_path / "nope.json")
    with pytest.raises(InputError, match="folder"):
        load_batch(tmp_path)
    with pytest.raises(FormatError, match="YAML"):
        load_batch(_write(tmp_path / "b.yaml", "jobs: []"))


def test_schema_and_literals_agree_with_the_library():
    from avatarkit.bake_writers import PreviewWriter
    from avatarkit.batch.engines import ENGINES
    from avatarkit.cli import batch_cmd
    from avatarkit.cli.main import COMMANDS
    from avatarkit.export.usd_stage import UsdWriteOptions
    from avatarkit.schemas import load_schema
    from avatarkit.sim.config import COLLISION_MODES, SimConfig

    schema = load_schema("batch")
    settings = schema["$defs"]["settings"]["properties"]
    assert set(settings["sim"]["properties"]) == {f.name for f in dataclasses.fields(SimConfig)}
    assert settings["sim"]["properties"]["collision"]["enum"] == list(COLLISION_MODES)
    usd_defaults = {f.name: f.default for f in dataclasses.fields(UsdWriteOptions) if f.name != "flush_bytes"}
    assert DEFAULT_OPTIONS["usd"] == usd_defaults
    assert set(settings["usd"]["properties"]) == set(usd_defaults)
    sig = inspect.signature(PreviewWriter)
    assert DEFAULT_OPTIONS["preview"] == {"size": sig.parameters["size"].default,
                                          "orbit": sig.parameters["orbit"].default}
    assert tuple(batch_cmd._ENGINES) == ENGINES
    assert COMMANDS["bake-batch"] == "avatarkit.cli.batch_cmd:bake_batch_cmd"


def test_sample_batch_file_is_valid(tmp_path):
    root = Path(__file__).resolve().parents[1]
    doc = json.loads((root / "samples" / "batch.json").read_text())
    # its inputs are made by the commands in its description; placeholders do for parsing
    clips = tmp_path / "batch_inputs" / "clips"
    clips.mkdir(parents=True)
    for kind in ("nod", "shake", "talk"):
        assert f"motion make {kind} -o samples/batch_inputs/clips/{kind}.npz" in doc["description"]
        (clips / f"{kind}.npz").write_bytes(b"x")
    batch = parse_batch(doc, base=tmp_path)
    assert [j.name for j in batch.jobs] == ["long/nod", "long/shake", "long/talk", "bob/nod", "bob/shake",
                                            "bob/talk", "bob/shake_static"]
    assert {o.kind for j in batch.jobs for o in j.outputs} == {"usd", "ply", "preview"}


# --- hashes and records -----------------------------------------------------------------------

def test_input_hashes_follow_content(tree):
    alice = tree / "avatars" / "alice"
    h = records.avatar_sha256(alice)
    (alice / "preview.png").write_bytes(b"an image")  # does not change what a bake makes
    (alice / ".partial.tmp").write_bytes(b"junk")
    assert records.avatar_sha256(alice) == h
    (alice / "avatar.json").write_text("{ }")
    assert records.avatar_sha256(alice) != h
    with pytest.raises(InputError, match="not found"):
        records.avatar_sha256(tree / "avatars" / "carol")

    clip = tree / "clips" / "nod.npz"
    c = records.clip_sha256(clip)
    clip.write_bytes(b"z")
    assert records.clip_sha256(clip) != c
    seq = tree / "clips" / "vhap_seq"
    s = records.clip_sha256(seq)
    (seq / "flame_param" / "00001.npz").write_bytes(b"w")
    assert records.clip_sha256(seq) != s
    with pytest.raises(InputError, match="no such file"):
        records.clip_sha256(tree / "clips" / "gone.npz")


def test_output_key_depends_on_every_input():
    base = ("a" * 64, "c" * 64, {"sim": {"substeps": 4}}, "usd", {"half": False})
    key = records.output_key(*base)
    assert key == records.output_key(*base)
    for i, other in enumerate(("b" * 64, "d" * 64, {"sim": {"substeps": 5}}, "ply", {"half": True})):
        changed = list(base)
        changed[i] = other
        assert records.output_key(*changed) != key


def test_record_vouches_only_for_complete_outputs(tmp_path):
    target = tmp_path / "x.usda"
    target.write_text("#usda 1.0\n")
    size = records.write_record(target, "preview", "k1", "job", {}, {}, 1.0)
    assert size == target.stat().st_size
    assert records.record_path(target) == tmp_path / "x.usda.job.json"
    assert records.is_up_to_date(target, "k1")
    assert not records.is_up_to_date(target, "k2")          # other inputs or settings
    target.write_text("#usda 1.0\n(\n")                    # changed or truncated
    assert not records.is_up_to_date(target, "k1")
    target.unlink()
    assert not records.is_up_to_date(target, "k1")
    records.record_path(target).write_text("{broken")
    assert records.read_record(target) is None and records.recorded_bytes(target) == 0
