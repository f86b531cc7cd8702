"""FLAME model pickles without chumpy: a synthetic FLAME-shaped pickle written with fake chumpy
classes (a `chumpy` module exists only while pickling), npz conversion and bad-file errors."""
from __future__ import annotations

import pickle
import sys
import types
import warnings

import numpy as np
import pytest
import scipy.sparse

from avatarkit.cli.main import main
from avatarkit.errors import FormatError, InputError
from avatarkit.head import HeadParams, load_flame, load_head_model, load_npz, save_npz
from avatarkit.head.lbs import lbs_reference
from avatarkit.head.template import icosphere
from avatarkit.rotations import axis_angle_to_matrix

N_SHAPE, N_EXPR = 300, 100


def flame_like_arrays(seed=0) -> dict:
    """FLAME's keys and shape pattern on a few hundred vertices: a head blob, two eyeballs."""
    rng = np.random.default_rng(seed)
    hv, hf = icosphere(2)
    hv = hv * [0.075, 0.11, 0.095] + [0.0, 0.0, -0.01]
    ev, ef = icosphere(1)
    eyes = [(ev * 0.012 + c, ef) for c in ([0.032, 0.03, 0.07], [-0.032, 0.03, 0.07])]
    v = np.concatenate([hv] + [e[0] for e in eyes])
    f = np.concatenate([hf, eyes[0][1] + len(hv), eyes[1][1] + len(hv) + len(ev)]).astype(np.uint32)
    V = len(v)
    w = np.zeros((V, 5))
    y = hv[:, 1]
    w[:len(hv), 0] = np.clip(-(y + 0.05) / 0.05, 0, 1)
    w[:len(hv), 2] = np.clip(-(y + 0.0) / 0.04, 0, 1) * (1 - w[:len(hv), 0]) * (hv[:, 2] > 0)
    w[:len(hv), 1] = 1 - w[:len(hv), 0] - w[:len(hv), 2]
    w[len(hv):len(hv) + len(ev), 3] = 1
    w[len(hv) + len(ev):, 4] = 1
    jr = np.zeros((5, V))
    jr[0, np.argsort(y)[:10]] = 0.1
    jr[1, np.argsort(np.abs(y + 0.03))[:10]] = 0.1
    jr[2, np.argsort(np.abs(y + 0.01))[:10]] = 0.1
    jr[3, len(hv):len(hv) + len(ev)] = 1.0 / len(ev)
    jr[4, len(hv) + len(ev):] = 1.0 / len(ev)
    return {
        "v_template": v, "f": f,
        "shapedirs": rng.normal(scale=1e-3, size=(V, 3, N_SHAPE + N_EXPR)),
        "posedirs": rng.normal(scale=1e-3, size=(V, 3, 36)),
        "J_regressor": scipy.sparse.csc_matrix(jr),
        "weights": w,
        "kintree_table": np.array([[4294967295, 0, 1, 1, 1], [0, 1, 2, 3, 4]], dtype=np.int64),
        "J": jr @ v, "bs_style": "lbs", "bs_type": "lrotmin",
    }


def write_chumpy_pickle(path, arrays, nested=True, protocol=2):
    """Pickle `arrays` with some of them wrapped in fake chumpy objects, as the official files
    are; the fake `chumpy` modules exist only during the dump."""
    ch_mod = types.ModuleType("chumpy.ch")
    reord_mod = types.ModuleType("chumpy.reordering")
    top = types.ModuleType("chumpy")

    class Ch:
        def __init__(self, x):
            self.x = x

        def __getstate__(self):
            return {"x": self.x, "_dirty_vars": set(), "_itr": None}

    class Select:  # an operator node: its operand lives under "a", an index array beside it
        def __init__(self, a, idxs):
            self.a, self.idxs = a, idxs

        def __getstate__(self):
            return {"idxs": self.idxs, "a": self.a, "preferred_shape": None}

    Ch.__module__, Ch.__qualname__ = "chumpy.ch", "Ch"
    Select.__module__, Select.__qualname__ = "chumpy.reordering", "Select"
    ch_mod.Ch, reord_mod.Select, top.ch, top.reordering = Ch, Select, ch_mod, reord_mod
    data = dict(arrays)
    for key in ("v_template", "shapedirs", "J"):
        if key in data:
            data[key] = Ch(data[key])
    if nested:
        data["weights"] = Select(Ch(data["weights"]), np.arange(3))
    saved = {k: sys.modules.get(k) for k in ("chumpy", "chumpy.ch", "chumpy.reordering")}
    sys.modules.update({"chumpy": top, "chumpy.ch": ch_mod, "chumpy.reordering": reord_mod})
    try:
        with open(path, "wb") as fh:
            pickle.dump(data, fh, protocol=protocol)
    finally:
        for k, v in saved.items():
            if v is None:
                sys.modules.pop(k, None)
            else:
                sys.modules[k] = v
    assert "chumpy" not in sys.modules


@pytest.fixture
def flame(tmp_path):
    arrays = flame_like_arrays()
    path = tmp_path / "generic_model.pkl"
    write_chumpy_pickle(path, arrays)
    return path, arrays


def test_loads_without_chumpy(flame, monkeypatch):
    path, raw = flame
    monkeypatch.setitem(sys.modules, "chumpy", None)  # importing chumpy now fails, installed or not
    m = load_flame(path)
    V = len(raw["v_template"])
    assert (m.num_vertices, m.num_faces, m.num_shape, m.num_expr, m.num_joints) == (V, len(raw["f"]), 300, 100, 5)
    np.testing.assert_allclose(m.v_template, raw["v_template"], atol=1e-7)
    np.testing.assert_array_equal(m.faces, raw["f"].astype(np.int32))
    np.testing.assert_allclose(m.shapedirs, raw["shapedirs"][:, :, :300], atol=1e-9)
    np.testing.assert_allclose(m.exprdirs, raw["shapedirs"][:, :, 300:], atol=1e-9)
    np.testing.assert_allclose(m.weights, raw["weights"], atol=1e-7)  # through the nested operator node
    assert scipy.sparse.issparse(m.J_regressor)
    np.testing.assert_allclose(m.J_regressor.toarray(), raw["J_regressor"].toarray(), atol=1e-7)
    assert m.posedirs.shape == (36, V * 3)
    assert m.kintree_parents.tolist() == [-1, 0, 1, 1, 1]
    assert m.name == "flame" and "sha256:" in m.source and str(path.name) in m.source


def test_forward_matches_flame_formulation(flame):
    """FLAME: posedirs (V, 3, 36) act on vec(R_j - I) of joints 1..4, blendshapes on [shape, expr]."""
    path, raw = flame
    m = load_flame(path)
    rng = np.random.default_rng(2)
    p = HeadParams(shape=rng.normal(size=300), expr=rng.normal(size=(2, 100)),
                   rotation=rng.normal(scale=0.3, size=(2, 3)),
                   neck=rng.normal(scale=0.3, size=(2, 3)), jaw=rng.normal(scale=0.3, size=(2, 3)),
                   eyes=rng.normal(scale=0.3, size=(2, 6)), translation=rng.normal(scale=0.1, size=(2, 3)))
    v, _ = m.forward(p)
    betas = np.concatenate([np.broadcast_to(p.shape, (2, 300)), p.expr], axis=1)
    shaped = raw["v_template"][None] + np.einsum("vcb,tb->tvc", raw["shapedirs"], betas)
    R = axis_angle_to_matrix(p.full_pose)
    feat = (R[:, 1:] - np.eye(3)).reshape(2, 36)
    offsets = np.einsum("vcp,tp->tvc", raw["posedirs"], feat)
    # joints come from the uncorrected mesh; the blended joint transforms pose the corrected one
    ref = []
    for t in range(2):
        _, A = lbs_reference(shaped[t:t + 1], raw["J_regressor"], m.kintree_parents, raw["weights"],
                             p.full_pose[t:t + 1], p.translation[t:t + 1])
        blend = np.einsum("vj,jab->vab", raw["weights"], A[0])
        ref.append(np.einsum("vab,vb->va", blend[:, :3, :3], shaped[t] + offsets[t]) + blend[:, :3, 3])
    np.testing.assert_allclose(v, np.stack(ref), atol=5e-6)


def test_regions_are_derived(flame):
    m = load_flame(flame[0])
    for name in ("scalp", "face", "neck", "left_eye", "right_eye", "eyes", "mouth_interior", "lips", "forehead"):
        assert name in m.regions
    nh = 162
    np.testing.assert_array_equal(m.regions["left_eye"], np.arange(nh, nh + 42))
    np.testing.assert_array_equal(m.regions["right_eye"], np.arange(nh + 42, nh + 84))
    top = np.argmax(m.v_template[:nh, 1])
    assert top in m.regions["scalp"]
    assert len(m.regions["neck"]) and m.v_template[m.regions["neck"], 1].max() < m.v_template[:nh, 1].mean()


def test_npz_round_trip(flame, tmp_path):
    m = load_flame(flame[0])
    out = tmp_path / "flame.npz"
    save_npz(m, out)
    back = load_npz(out)
    for key in ("faces", "v_template", "shapedirs", "exprdirs", "posedirs", "weights", "kintree_parents"):
        np.testing.assert_array_equal(getattr(back, key), getattr(m, key))
    np.testing.assert_allclose(back.J_regressor, m.J_regressor.toarray())
    assert back.regions.keys() == m.regions.keys()
    assert back.source == m.source and back.name == "flame"
    p = HeadParams(jaw=[[0.2, 0, 0]], expr=np.ones((1, 100)) * 0.3, neck=[[0.1, 0.2, 0]])
    np.testing.assert_allclose(back.forward(p)[0], m.forward(p)[0], atol=1e-6)
    assert load_head_model(out).num_vertices == m.num_vertices


def test_template_npz_round_trip(tmp_path):
    from avatarkit.head import load_template

    m = load_template()
    save_npz(m, tmp_path / "t.npz")
    back = load_npz(tmp_path / "t.npz")
    assert back.expression_names == m.expression_names and back.posedirs is None
    p = HeadParams(expr=np.eye(1, m.num_expr, 2), jaw=[[0.2, 0, 0]])
    np.testing.assert_allclose(back.forward(p)[0], m.forward(p)[0], atol=1e-7)


def test_flame_2023_style_plain_arrays(tmp_path):
    """flame2023.pkl-like: fewer chumpy objects, a dense J_regressor, protocol 4."""
    raw = flame_like_arrays(seed=1)
    raw["J_regressor"] = raw["J_regressor"].toarray()
    path = tmp_path / "flame2023.pkl"
    write_chumpy_pickle(path, raw, nested=False, protocol=4)
    m = load_flame(path)
    np.testing.assert_allclose(m.J_regressor, raw["J_regressor"], atol=1e-7)
    assert m.num_expr == 100


def test_old_module_paths(flame, tmp_path):
    """Files written by Python 2 / old numpy and scipy name numpy.core and scipy.sparse.csc."""
    data = flame[0].read_bytes()
    assert b"numpy._core.multiarray\n" in data and b"scipy.sparse._csc\ncsc_matrix" in data  # protocol 2
    old = data.replace(b"numpy._core.multiarray\n", b"numpy.core.multiarray\n")
    old = old.replace(b"scipy.sparse._csc\ncsc_matrix", b"scipy.sparse.csc\ncsc_matrix")
    path = tmp_path / "old.pkl"
    path.write_bytes(old)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        m = load_flame(path)
    np.testing.assert_allclose(m.J_regressor.toarray(), flame[1]["J_regressor"].toarray(), atol=1e-7)


def test_cli_convert(flame, tmp_path, capsys):
    out = tmp_path / "flame.npz"
    assert main(["head", "convert", str(flame[0]), "-o", str(out)]) == 0
    assert "300 shape and 100 expression" in capsys.readouterr().out
    assert load_npz(out).num_vertices == len(flame[1]["v_template"])
    mesh = tmp_path / "flame.obj"
    assert main(["head", "export", "--head-model", str(out), "-o", str(mesh), "-q"]) == 0
    assert mesh.stat().st_size > 0


# --- bad input ---------------------------------------------------------------------------------

def _dump(path, obj):
    with open(path, "wb") as fh:
        pickle.dump(obj, fh, protocol=2)
    return path


def test_corrupt_and_truncated_files(flame, tmp_path):
    bad = tmp_path / "bad.pkl"
    bad.write_bytes(b"\x80\x02 this is not a pickle at all")
    with pytest.raises(FormatError, match="bad.pkl"):
        load_flame(bad)
    cut = tmp_path / "cut.pkl"
    cut.write_bytes(flame[0].read_bytes()[:5000])
    with pytest.raises(FormatError, match="cut.pkl.*not a readable FLAME model"):
        load_flame(cut)
    with pytest.raises(FormatError, match="not a FLAME model"):
        load_flame(_dump(tmp_path / "list.pkl", [1, 2, 3]))
    with pytest.raises(InputError, match="not found"):
        load_flame(tmp_path / "missing.pkl")


def test_refuses_to_run_code(tmp_path):
    class Evil:
        def __reduce__(self):
            import os
            return (os.system, ("echo pwned > " + str(tmp_path / "pwned"),))
    with pytest.raises(FormatError, match="refusing to load"):
        load_flame(_dump(tmp_path / "evil.pkl", {"v_template": Evil()}))
    assert not (tmp_path / "pwned").exists()


@pytest.mark.parametrize("key,value,match", [
    ("shapedirs", None, "missing key 'shapedirs'"),
    ("weights", "drop-column", "key 'weights' must have shape"),
    ("f", np.array([[0, 1, 99999]]), "key 'f'"),
    ("kintree_table", np.array([[4294967295, 0, 0, 1, 1], [0, 1, 2, 3, 4]]), "kintree_table"),
    ("posedirs", np.zeros((5, 3, 36)), "key 'posedirs' must have shape"),
    ("J_regressor", scipy.sparse.csc_matrix(np.zeros((4, 10))), "key 'J_regressor' must have shape"),
    ("v_template", "not an array", "key 'v_template'"),
])
def test_missing_keys_and_wrong_shapes_name_the_key(tmp_path, key, value, match):
    raw = flame_like_arrays()
    if value is None:
        del raw[key]
    elif isinstance(value, str) and value == "drop-column":
        raw[key] = raw[key][:, :4]
    else:
        raw[key] = value
    path = tmp_path / "broken.pkl"
    write_chumpy_pickle(path, raw, nested=False)
    with pytest.raises(FormatError, match=match) as info:
        load_flame(path)
    assert "broken.pkl" in str(info.value)


def test_bad_npz(tmp_path):
    p = tmp_path / "x.npz"
    np.savez(p, faces=np.zeros((1, 3), np.int32))
    with pytest.raises(FormatError, match="missing key 'v_template'"):
        load_npz(p)
    q = tmp_path / "y.npz"
    q.write_bytes(b"garbage")
    with pytest.raises(FormatError, match="y.npz"):
        load_npz(q)
    with pytest.raises(InputError, match="unknown head model format"):
        load_head_model(tmp_path / "model.obj")


def test_cli_errors_are_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.pkl"
    bad.write_bytes(b"nope")
    assert main(["head", "convert", str(bad), "-o", str(tmp_path / "o.npz")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "bad.pkl" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o.npz").exists()
