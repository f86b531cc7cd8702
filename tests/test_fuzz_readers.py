"""Fuzz every reader (hypothesis): valid files of each kind, damaged at random (bytes flipped,
cut, spliced, numbers in headers and documents replaced by hostile ones), must load or fail with
one `AvatarKitError` line (exit 2 at the CLI): never another exception (a traceback, exit 1), and
never an allocation beyond ALLOC_BOUND (traced with tracemalloc: numpy and Python memory).

The default suite runs FAST_EXAMPLES derandomised cases per reader; the slow-marked run
(`pytest -m slow tests/test_fuzz_readers.py`) runs SLOW_EXAMPLES random ones.
"""
from __future__ import annotations

import json
import re
import shutil
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from avatarkit.cli.main import main
from avatarkit.errors import AvatarKitError
from helpers import random_gaussians

FAST_EXAMPLES = 8
SLOW_EXAMPLES = 300
#: the most any one read of these small damaged files may allocate (numpy + Python, traced)
ALLOC_BOUND = 64 << 20

HOSTILE_NUMBERS = [0, 1, -1, 2**31 - 1, 2**31, 2**32 + 7, 2**63 - 1, 10**11, 10**30, -(10**11)]
HOSTILE_FLOATS = [float("nan"), float("inf"), float("-inf"), 1e300, 1e-300, -0.0, 0.0, 1e38, 3.4e38]


# --- damage ----------------------------------------------------------------------------------------
@st.composite
def damaged(draw, data: bytes) -> bytes:
    """`data` after 1-4 random edits: flip, cut, splice in random bytes, duplicate a span, or
    replace a decimal number (text headers) with a hostile one."""
    out = bytearray(data)
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["flip", "cut", "splice", "dup", "number", "zero"]))
        n = len(out)
        if n == 0:
            out += draw(st.binary(min_size=1, max_size=64))
            continue
        i = draw(st.integers(0, n - 1))
        if op == "flip":
            out[i] ^= draw(st.integers(1, 255))
        elif op == "cut":
            del out[i:]
        elif op == "splice":
            out[i:i] = draw(st.binary(min_size=1, max_size=64))
        elif op == "dup":
            j = draw(st.integers(i, min(n, i + 256)))
            out[j:j] = out[i:j]
        elif op == "zero":
            j = draw(st.integers(i, min(n, i + 64)))
            out[i:j] = bytes(j - i)
        else:
            numbers = list(re.finditer(rb"\d+", bytes(out[:4096])))
            if numbers:
                m = draw(st.sampled_from(numbers))
                value = str(draw(st.sampled_from(HOSTILE_NUMBERS))).encode()
                out[m.start():m.end()] = value
    return bytes(out)


json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-(10**12), 10**12) | st.sampled_from(HOSTILE_FLOATS)
    | st.floats(allow_nan=True) | st.text(max_size=8),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=6), children, max_size=4),
    max_leaves=12)


@st.composite
def damaged_doc(draw, doc):
    """`doc` (parsed JSON) with 1-3 values somewhere inside replaced by random JSON values."""
    doc = json.loads(json.dumps(doc))
    for _ in range(draw(st.integers(1, 3))):
        paths = []

        def walk(node, path):
            paths.append(path)
            if isinstance(node, dict):
                for k, v in node.items():
                    walk(v, path + [k])
            elif isinstance(node, list):
                for k, v in enumerate(node[:8]):
                    walk(v, path + [k])

        walk(doc, [])
        path = draw(st.sampled_from(paths[1:] or paths))
        value = draw(json_values)
        if not path:
            doc = value
            continue
        node = doc
        for k in path[:-1]:
            node = node[k]
        node[path[-1]] = value
    return json.dumps(doc, allow_nan=True)


# --- the check -------------------------------------------------------------------------------------
def check(read, path: Path, bound: int = ALLOC_BOUND) -> None:
    """`read(path)` succeeds or raises one single-line AvatarKitError; allocation bounded."""
    tracemalloc.start()
    try:
        read(path)
    except AvatarKitError as e:
        assert "\n" not in str(e), str(e)
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    assert peak < bound, f"{peak / 2**20:.0f} MiB"


def check_cli(argv, capsys) -> None:
    """The CLI on the damaged file: exit 0, or exit 2 with one line on stderr."""
    code = main([str(a) for a in argv])
    _, err = capsys.readouterr()
    assert code in (0, 2), err
    if code == 2:
        lines = [x for x in err.strip().splitlines() if not x.startswith("warning:")]
        assert len(lines) == 1 and lines[0].startswith("error: "), err


# --- seeds: one valid file of each kind --------------------------------------------------------------
@pytest.fixture(scope="module")
def seeds(tmp_path_factory):
    from avatarkit.gaussians.ply import write_ply
    from avatarkit.gaussians.spz import write_spz
    from avatarkit.gaussians.usd import save_usd
    from avatarkit.motion import make_clip, save_clip

    d = tmp_path_factory.mktemp("seeds")
    gs = random_gaussians(12, sh_degree=1, seed=2, extras=("part",))
    write_ply(d / "s.ply", gs)
    write_spz(d / "s.spz", gs)
    save_usd(d / "s.usda", gs)
    save_usd(d / "s.usdc", gs)
    clip = make_clip("nod", frames=3, fps=25, expr_dims=4)
    save_clip(d / "c.npz", clip)
    save_clip(d / "c.json", clip)
    from avatarkit.export.images import write_png
    img = np.random.default_rng(0).uniform(size=(24, 32, 3))
    write_png(d / "i.png", img)
    from avatarkit.recon.image_io import write_image
    write_image(d / "i.jpg", (img * 255).astype(np.uint8))
    (d / "b.json").write_text(json.dumps({
        "format": "avatarkit.batch", "version": 1,
        "defaults": {"outputs": {"usd": "{name}.usdc"}, "sim": {"substeps": 2}, "preroll": 0.2},
        "jobs": [{"avatar": "av", "clip": "c.npz", "name": "{avatar}/{clip}"}]}))
    return d


def _bytes_case(seeds, name, tmp_path_factory):
    return (seeds / name).read_bytes()


def _fuzz(max_examples: int, derandomize: bool):
    return settings(max_examples=max_examples, deadline=None, derandomize=derandomize,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow,
                                           HealthCheck.data_too_large])


def _readers():
    from avatarkit.batch import load_batch
    from avatarkit.gaussians.ply import read_ply
    from avatarkit.gaussians.spz import read_spz
    from avatarkit.gaussians.usd_read import load_usd
    from avatarkit.motion import load_clip
    from avatarkit.recon.image_io import read_image, read_mask

    return {
        "s.ply": [lambda p: read_ply(p, decoder="numpy"), lambda p: read_ply(p, decoder="auto")],
        "s.spz": [read_spz],
        "s.usda": [load_usd],
        "s.usdc": [load_usd],
        "c.npz": [load_clip],
        "i.png": [read_image, lambda p: read_mask(p, (24, 32))],
        "i.jpg": [read_image],
    }


BYTE_KINDS = ["s.ply", "s.spz", "s.usda", "s.usdc", "c.npz", "i.png", "i.jpg"]
INSPECTABLE = {"s.ply", "s.spz", "s.usda", "s.usdc", "c.npz"}


def _bytes_test(name, seeds, tmp_path, capsys, data):
    path = tmp_path / f"x{Path(name).suffix}"
    path.write_bytes(data)
    for read in _readers()[name]:
        check(read, path)
    if name in INSPECTABLE:
        check_cli(["inspect", path], capsys)


@pytest.mark.parametrize("name", BYTE_KINDS)
def test_damaged_files(name, seeds, tmp_path, capsys):
    seed = (seeds / name).read_bytes()

    @_fuzz(FAST_EXAMPLES, True)
    @given(damaged(seed))
    def case(data):
        _bytes_test(name, seeds, tmp_path, capsys, data)

    case()


@pytest.mark.slow
@pytest.mark.parametrize("name", BYTE_KINDS)
def test_damaged_files_long_run(name, seeds, tmp_path, capsys):
    seed = (seeds / name).read_bytes()

    @_fuzz(SLOW_EXAMPLES, False)
    @given(damaged(seed))
    def case(data):
        _bytes_test(name, seeds, tmp_path, capsys, data)

    case()


# --- JSON documents: clips, batch files, avatar manifests ----------------------------------------------
def _json_kinds(seeds, avatar_folder):
    from avatarkit.avatar import read_manifest
    from avatarkit.batch import load_batch
    from avatarkit.motion import load_clip

    return {
        "clip": (json.loads((seeds / "c.json").read_text()), "x.json", load_clip),
        "batch": (json.loads((seeds / "b.json").read_text()), "b.json", load_batch),
        "manifest": (json.loads((avatar_folder / "avatar.json").read_text()), "avatar.json",
                     lambda p: read_manifest(p.parent)),
    }


@pytest.fixture(scope="module")
def avatar_folder(tmp_path_factory):
    from test_avatar import saved_avatar
    return saved_avatar(tmp_path_factory)


def _json_test(kind, seeds, avatar_folder, tmp_path, text):
    doc, name, read = _json_kinds(seeds, avatar_folder)[kind]
    folder = tmp_path / kind
    folder.mkdir(exist_ok=True)
    path = folder / name
    path.write_text(text)
    check(read, path)


@pytest.mark.parametrize("kind", ["clip", "batch", "manifest"])
def test_damaged_json_documents(kind, seeds, avatar_folder, tmp_path):
    doc = _json_kinds(seeds, avatar_folder)[kind][0]

    @_fuzz(FAST_EXAMPLES * 2, True)
    @given(damaged_doc(doc))
    def case(text):
        _json_test(kind, seeds, avatar_folder, tmp_path, text)

    case()


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["clip", "batch", "manifest"])
def test_damaged_json_documents_long_run(kind, seeds, avatar_folder, tmp_path):
    doc = _json_kinds(seeds, avatar_folder)[kind][0]

    @_fuzz(SLOW_EXAMPLES, False)
    @given(damaged_doc(doc) | damaged(json.dumps(doc).encode()).map(lambda b: b.decode("latin-1")))
    def case(text):
        _json_test(kind, seeds, avatar_folder, tmp_path, text)

    case()


def test_tampered_avatar_folders_load_or_fail_in_one_line(avatar_folder, tmp_path):
    """Each file of an avatar folder damaged in turn: `load_avatar` loads it or says which file."""
    from avatarkit.avatar import load_avatar

    tracemalloc.start()
    load_avatar(avatar_folder)
    clean_peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    rng = np.random.default_rng(7)
    for f in sorted(p.name for p in avatar_folder.iterdir() if p.is_file()):
        for trial in range(2):
            folder = tmp_path / f"{f}-{trial}"
            shutil.copytree(avatar_folder, folder)
            data = bytearray((folder / f).read_bytes())
            if trial == 0:
                del data[len(data) // 2:]
            else:
                for i in rng.integers(0, len(data), 8):
                    data[i] ^= 0x5A
            (folder / f).write_bytes(bytes(data))
            # a whole avatar is larger than one small file: bounded by what a clean load takes
            check(load_avatar, folder, bound=2 * clean_peak + ALLOC_BOUND)


def test_a_crate_whose_values_lie_outside_the_file_is_a_format_error(seeds, tmp_path, capsys):
    """The long run's find (session 12): one byte of the seed's crate changed (offset 737,
    0 -> 1) opens as a stage and fails only when the splats' values are read; that failure is
    USD's Tf.ErrorException, which must come out as a FormatError naming the file."""
    from avatarkit.errors import FormatError
    from avatarkit.gaussians.usd_read import load_usd

    data = bytearray((seeds / "s.usdc").read_bytes())
    assert data[737] == 0, "the seed's crate changed: find a new damaged byte with the long run"
    data[737] = 1
    path = tmp_path / "damaged.usdc"
    path.write_bytes(bytes(data))
    with pytest.raises(FormatError, match="damaged.usdc.*not a readable USD file"):
        load_usd(path)
    check_cli(["render", path, "-o", tmp_path / "r.png"], capsys)


@pytest.mark.parametrize("attribute", ["opacities", "scales", "positions", "extent"])
def test_a_damaged_type_name_in_a_usda_is_a_format_error(seeds, tmp_path, capsys, attribute):
    """The long run's find (session 13): a damaged type name in a .usda (`float[]` -> `fl0at[]`)
    makes USD hand back an `Sdf.UnregisteredValue` instead of numbers, which numpy refused with a
    TypeError; it must be a FormatError naming the file and the attribute."""
    from avatarkit.errors import FormatError
    from avatarkit.gaussians.usd_read import load_usd

    text = (seeds / "s.usda").read_text()
    damaged, count = re.subn(r"\b\w+(\[\] " + attribute + r" =)", r"fl0at\1", text)
    assert count == 1, f"the seed's .usda has no {attribute} array: find a new case with the long run"
    path = tmp_path / "damaged.usda"
    path.write_text(damaged)
    if attribute != "extent":  # the reader computes its own bounds
        with pytest.raises(FormatError, match=f"damaged.usda.*{attribute} does not hold .* values"):
            load_usd(path)
    check_cli(["inspect", path], capsys)
