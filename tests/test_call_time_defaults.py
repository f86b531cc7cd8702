"""Module switches are read when a function is called, not frozen as default arguments.

`def f(x=MIN_WEIGHT)` binds MIN_WEIGHT's value at import: setting `module.MIN_WEIGHT` later (as
the docs and benchmarks tell users to) would change nothing. The library writes `x=None` and
reads the constant in the body (`x = MIN_WEIGHT if x is None else x`; where None is itself a
value of the switch, a private sentinel `_UNSET = object()` stands for "the module's value").
The scan below fails on any new frozen default; the table checks that every call-time default
still names a constant that exists (a renamed constant no longer fails at import, only when
the function runs); the behaviour tests set a documented switch and see its effect."""
from __future__ import annotations

import ast
import importlib
import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from avatarkit.render.camera import Camera
from helpers import plane_grid, region_model

ROOT = Path(__file__).resolve().parents[1]
#: the sources the package installs (cli/ installs as avatarkit.cli), and the scripts whose
#: constants users set (benchmarks, tools)
SOURCES = ("avatarkit", "cli", "benchmarks", "tools")
PACKAGES = ("avatarkit", "cli")  # importable as modules: the table below imports them
_UPPER = re.compile(r"^_?[A-Z][A-Z0-9_]*$")


def _files(tops=SOURCES):
    for top in tops:
        yield from sorted((ROOT / top).rglob("*.py"))


def _sentinels(tree: ast.Module) -> set[str]:
    """Module-level names bound to a bare `object()` (call-time default markers, not switches)."""
    out = set()
    for node in tree.body:
        if (isinstance(node, ast.Assign) and isinstance(node.value, ast.Call) and not node.value.args
                and isinstance(node.value.func, ast.Name) and node.value.func.id == "object"):
            out |= {t.id for t in node.targets if isinstance(t, ast.Name)}
    return out


def _functions(tree: ast.Module):
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            yield node


def frozen_defaults(path: Path) -> list[str]:
    """'file:line function(param=default)' for every default argument that reads an UPPERCASE
    constant (`NAME`, `module.NAME`, or an expression of one such as `NAME[:3]`) at import."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    allowed = _sentinels(tree)
    out = []
    for f in _functions(tree):
        a = f.args
        pos = a.posonlyargs + a.args
        pairs = list(zip(pos[len(pos) - len(a.defaults):], a.defaults))
        pairs += [(k, d) for k, d in zip(a.kwonlyargs, a.kw_defaults) if d is not None]
        for arg, default in pairs:
            for x in ast.walk(default):
                named = isinstance(x, ast.Name) and _UPPER.match(x.id) and x.id not in allowed
                moduled = (isinstance(x, ast.Attribute) and _UPPER.match(x.attr) and isinstance(x.value, ast.Name)
                           and x.value.id[:1].islower())
                if named or moduled:
                    rel = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path.name
                    out.append(f"{rel}:{default.lineno} {getattr(f, 'name', 'lambda')}"
                               f"({arg.arg}={ast.unparse(default)})")
                    break
    return out


def test_the_scan_finds_a_frozen_default(tmp_path):
    """The scan's own known cases: the forms it must flag, and what it must let pass."""
    src = tmp_path / "m.py"
    src.write_text("import numpy as np\nfrom x import LIMIT\nSIZE = 3\n_UNSET = object()\n"
                   "def a(n=SIZE): pass\n"
                   "def b(*, k=np.PINF, j=LIMIT[:2]): pass\n"
                   "g = lambda s=SIZE: s\n"
                   "def ok(n=None, m=_UNSET, s='SIZE', t=3, u=Mode.FAST, v=size): pass\n")
    found = frozen_defaults(src)
    assert [s.split(" ", 1)[1] for s in found] == ["a(n=SIZE)", "b(k=np.PINF)", "b(j=LIMIT[:2])", "lambda(s=SIZE)"]


def test_no_module_constant_is_frozen_as_a_default_argument():
    found = [s for p in _files() for s in frozen_defaults(p)]
    assert not found, ("default arguments frozen at import (write `x=None` and resolve it in the body, "
                       "docs/development.md):\n" + "\n".join(found))


#: dataclass fields that may default to an UPPERCASE name: labels and format names, not switches
FIELD_LABELS = {"ReassignConfig.hair_label", "ReassignConfig.background_label", "ReassignConfig.bald_label",
                "UsdWriteOptions.prim_path"}


def _is_dataclass_decorator(d) -> bool:
    f = d.func if isinstance(d, ast.Call) else d
    return (isinstance(f, ast.Name) and f.id == "dataclass") or (isinstance(f, ast.Attribute) and f.attr == "dataclass")


def frozen_fields(path: Path) -> list[str]:
    """'file:line Class.field = default' for every dataclass field whose default reads an
    UPPERCASE constant at import (`x: int = NAME`); `field(default_factory=lambda: NAME)` reads
    it when the instance is made and passes."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out = []
    for c in ast.walk(tree):
        if not (isinstance(c, ast.ClassDef) and any(_is_dataclass_decorator(d) for d in c.decorator_list)):
            continue
        for st in c.body:
            if not (isinstance(st, ast.AnnAssign) and isinstance(st.target, ast.Name) and st.value is not None):
                continue
            if f"{c.name}.{st.target.id}" in FIELD_LABELS or isinstance(st.value, ast.Lambda):
                continue
            lambdas = {id(n) for x in ast.walk(st.value) if isinstance(x, ast.Lambda) for n in ast.walk(x.body)}
            if any(id(x) not in lambdas and ((isinstance(x, ast.Name) and _UPPER.match(x.id))
                                             or (isinstance(x, ast.Attribute) and _UPPER.match(x.attr)))
                   for x in ast.walk(st.value)):
                rel = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path.name
                out.append(f"{rel}:{st.lineno} {c.name}.{st.target.id} = {ast.unparse(st.value)}")
    return out


def test_the_field_scan_finds_a_frozen_field(tmp_path):
    src = tmp_path / "m.py"
    src.write_text("from dataclasses import dataclass, field\nimport m2\nSIZE = 3\n"
                   "@dataclass\nclass A:\n    a: int = SIZE\n    b: float = m2.LIMIT\n"
                   "    c: int = field(default=SIZE)\n    d: int = field(default_factory=lambda: SIZE)\n"
                   "    e: str = 'SIZE'\n    f: int = 3\n"
                   "class NotData:\n    g: int = SIZE\n")
    found = [s.split(" ", 1)[1] for s in frozen_fields(src)]
    assert found == ["A.a = SIZE", "A.b = m2.LIMIT", "A.c = field(default=SIZE)"]


def test_no_option_field_freezes_a_module_constant():
    found = [s for p in _files() for s in frozen_fields(p)]
    assert not found, ("dataclass fields frozen at import (write `field(default_factory=lambda: NAME)`, "
                       "docs/development.md):\n" + "\n".join(found))


@pytest.mark.parametrize("cls_path, name, module, constant, value", [
    ("avatarkit.track.tracker:TrackOptions", "calibration_frames", "avatarkit.track.tracker", "CALIBRATION_FRAMES", 7),
    ("avatarkit.bake:BakeConfig", "hair_batch", "avatarkit.bake", "HAIR_BATCH", 5),
    ("avatarkit.track.evaluate:EvalOptions", "alpha_threshold", "avatarkit.track.metrics", "ALPHA_THRESHOLD", 0.25),
    ("avatarkit.track.evaluate:EvalOptions", "head_on", "avatarkit.track.neck", "DEFAULT_HEAD_ON", "head"),
    ("avatarkit.cage.deform:CageDeformer", "axis_sigma", "avatarkit.cage.points", "AXIS_SIGMA", 0.5),
])
def test_option_fields_read_their_switch_when_made(monkeypatch, cls_path, name, module, constant, value):
    import dataclasses
    mod, cls = cls_path.split(":")
    f = {x.name: x for x in dataclasses.fields(getattr(importlib.import_module(mod), cls))}[name]
    monkeypatch.setattr(importlib.import_module(module), constant, value)
    assert f.default_factory() == value


def _call_time_defaults():
    """(module, function, param, reference) for every `param = REF if param is None|_UNSET else param`
    statement at the top of a function whose `param` defaults to that marker, REF a module
    global (a name the function imports itself is checked when it runs)."""
    rows = []
    for path in _files(PACKAGES):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        module = ".".join(path.relative_to(ROOT).with_suffix("").parts)
        module = "avatarkit." + module if module.startswith("cli.") else module
        for f in _functions(tree):
            if isinstance(f, ast.Lambda):
                continue
            a = f.args
            pos = a.posonlyargs + a.args
            defaults = dict(zip([p.arg for p in pos[len(pos) - len(a.defaults):]], a.defaults))
            defaults.update({k.arg: d for k, d in zip(a.kwonlyargs, a.kw_defaults) if d is not None})
            local = {x.id for x in ast.walk(f) if isinstance(x, ast.Name) and isinstance(x.ctx, ast.Store)}
            local |= {(n.asname or n.name).split(".")[0] for x in ast.walk(f)
                      if isinstance(x, (ast.Import, ast.ImportFrom)) for n in x.names}
            for st in f.body:
                if not (isinstance(st, ast.Assign) and len(st.targets) == 1 and isinstance(st.targets[0], ast.Name)
                        and isinstance(st.value, ast.IfExp) and isinstance(st.value.test, ast.Compare)):
                    continue
                name, test = st.targets[0].id, st.value.test
                ref = st.value.body
                base = ref.value if isinstance(ref, ast.Subscript) else ref
                upper = ((isinstance(base, ast.Name) and _UPPER.match(base.id) and base.id not in local)
                         or (isinstance(base, ast.Attribute) and _UPPER.match(base.attr)))
                if (upper and name in defaults and isinstance(test.ops[0], ast.Is)
                        and isinstance(test.left, ast.Name) and test.left.id == name
                        and ast.unparse(test.comparators[0]) == ast.unparse(defaults[name])):
                    rows.append((module, f.name, name, ast.unparse(ref)))
    return rows


CALL_TIME = _call_time_defaults()


def test_the_library_reads_its_switches_at_call_time():
    # session 21 converted 164 defaults; more is fine, far fewer means the table lost its rows
    assert len(CALL_TIME) >= 160


@pytest.mark.parametrize("module, function, param, ref", CALL_TIME,
                         ids=[f"{m.rsplit('.', 1)[-1]}.{f}.{p}" for m, f, p, _ in CALL_TIME])
def test_each_call_time_default_names_a_constant_that_exists(module, function, param, ref):
    mod = importlib.import_module(module)
    eval(compile(ref, module, "eval"), vars(mod))  # raises NameError / AttributeError if it is gone


# ---- behaviour: a documented switch set after import takes effect -----------------------------

SIZE = 96


_plane = plane_grid


def _camera():
    return Camera.look_at((0.0, 0.0, 0.5), (0.0, 0.0, 0.0), width=SIZE, height=SIZE, fov_deg=40)


def test_frame_hull_margin_rounds_and_min_frames_are_read_when_called(monkeypatch):
    """`track.frame_hull`: MARGIN dilates the person before the wall starts; MIN_FRAMES is how many
    frames must show a Gaussian before they may clear it (carve_frames and carve)."""
    from avatarkit.track import frame_hull as fh

    person = np.zeros((SIZE, SIZE), bool)
    person[:, :SIZE // 2] = True
    for margin in (1, 6):
        monkeypatch.setattr(fh, "MARGIN", margin)
        wall = fh.wall_image(person)
        # the wall starts `margin` px past the person's edge
        assert wall[SIZE // 2, :SIZE // 2 + margin].sum() == 0 and wall[SIZE // 2, SIZE // 2 + margin:].all()
    xs = ys = np.arange(-0.1, 0.1 + 1e-9, 0.01)
    g = _plane(xs, ys)
    views = [SimpleNamespace(gaussians=g, camera=_camera())] * 2
    walls = [fh.wall_image(person)] * 2
    monkeypatch.setattr(fh, "MIN_FRAMES", 3)            # two frames: too few to clear anything
    assert not fh.carve(views, walls).cleared.any()
    monkeypatch.setattr(fh, "MIN_FRAMES", 2)
    assert fh.carve(views, walls).cleared.any()
    monkeypatch.setattr(fh, "ROUNDS", 0)                # no round: nothing cleared
    assert fh.carve(views, walls).info["total"] == 0


def test_frame_colours_min_weight_is_read_when_called(monkeypatch):
    """`track.frame_colours.MIN_WEIGHT`: a Gaussian shows in a frame (and takes its colour) when
    its blending weight over the mask reaches it; set above any Gaussian's weight, none does."""
    from avatarkit.track import frame_colours as fc

    xs = ys = np.arange(-0.05, 0.05 + 1e-9, 0.01)
    g = _plane(xs, ys, rgb=0.5)
    image = np.full((SIZE, SIZE, 3), 200, np.uint8)
    view = fc.FrameView(g, _camera(), image, np.ones((SIZE, SIZE), bool))
    select = np.ones(len(g), bool)
    assert fc.frame_shows(view).all()
    assert fc.refine_colours_frames([view], select, iterations=1).updated.all()
    monkeypatch.setattr(fc, "MIN_WEIGHT", 1e9)
    assert not fc.frame_shows(view).any()
    assert not fc.refine_colours_frames([view], select, iterations=1).updated.any()


def test_fusion_selection_follows_regions_and_keeps_none_for_every_gaussian(monkeypatch):
    """`frame_colours.REGIONS` is the default of `fusion_selection`'s regions; an explicit None
    still means every bald Gaussian (the sentinel, not None, stands for the module's value)."""
    from avatarkit.track import frame_colours as fc

    model = region_model(np.array([[0, 1, 2], [2, 3, 4], [4, 5, 6]]),
                         {"neck": np.array([0, 1]), "lips": np.array([3, 4, 5])}, 7)
    bald = _plane(np.array([0.0, 0.1]), np.array([0.0, 0.1])).replace(
        extras={"binding": np.array([0, 1, 2, 0], np.int32)})
    avatar = SimpleNamespace(head_model=model, bald=bald, hair=_plane(np.array([0.0]), np.array([0.0])))
    monkeypatch.setattr(fc, "REGIONS", ("neck",))
    np.testing.assert_array_equal(fc.fusion_selection(avatar), [True, False, False, True, False])
    monkeypatch.setattr(fc, "REGIONS", ("lips",))
    np.testing.assert_array_equal(fc.fusion_selection(avatar), [False, True, True, False, False])
    np.testing.assert_array_equal(fc.fusion_selection(avatar, None), [True, True, True, True, False])


def test_the_near_plane_is_read_when_called_by_the_renderer_and_its_reference(monkeypatch):
    """`render.pipeline.NEAR_PLANE` culls what lies nearer the camera; the numpy reference
    (`render.reference`, which imports the constant) reads the pipeline's value too."""
    from avatarkit.render import pipeline, reference

    g = _plane(np.array([-0.01, 0.01]), np.array([0.0]), z=0.2)   # 0.3 m in front of the camera
    cam = _camera()
    assert pipeline.project_gaussians(g, cam).visible.all()
    assert reference.project_reference(g, cam).visible.all()
    monkeypatch.setattr(pipeline, "NEAR_PLANE", 0.4)
    assert not pipeline.project_gaussians(g, cam).visible.any()
    assert not reference.project_reference(g, cam).visible.any()
    assert pipeline.render(g, cam).alpha.max() == 0.0


# switches another module used to copy in at import (`from avatarkit.X import NAME` at the top,
# read in a function body): each now read from its home when called (session 21)
READ_AT_HOME = {
    "avatarkit/recon/bald.py": {"MATCH_D2"},
    "avatarkit/recon/hair_fill.py": {"HAIR_THICKNESS"},
    "avatarkit/recon/hair_directions.py": {"REFERENCE_WEIGHT"},
    "avatarkit/recon/bald_discs.py": {"MIN_FACING"},
    "avatarkit/recon/hair_strands.py": {"DEPTH_TOL"},
    "avatarkit/recon/lift.py": {"FILL_SHARE", "HAIR_REFERENCE_COUNT", "HAIR_THICKNESS", "HAIR_WIDTH", "MARGIN", "SEGMENT"},
    "avatarkit/recon/hair_outline.py": {"ALPHA_MIN"},
    "avatarkit/recon/hair_hull.py": {"HAIR_THICKNESS", "MAX_SHELL", "ALPHA_MIN", "EDGE_MARGIN", "DEPTH_TOL"},
    "avatarkit/track/video_build.py": {"TURNED_EDGE"},
}


@pytest.mark.parametrize("path", sorted(READ_AT_HOME))
def test_switches_of_other_modules_are_not_copied_in_at_import(path):
    """None of these switches is bound by a module-level `from avatarkit.X import NAME` in the
    module that reads it (a copy made at import that setting the home's constant never reaches)."""
    import ast

    tree = ast.parse((ROOT / path).read_text())
    copied = {a.asname or a.name for n in tree.body if isinstance(n, ast.ImportFrom)
              and (n.module or "").startswith("avatarkit") for a in n.names}
    assert not (copied & READ_AT_HOME[path]), f"{path} copies {sorted(copied & READ_AT_HOME[path])} at import"


def test_a_switch_of_another_module_reaches_the_reader(monkeypatch):
    """`bald_discs.photo_weight` reads `visibility.MIN_FACING` when called: the photo's share is 0
    at the floor and 1 from `GRAZING` up, wherever the floor is set."""
    from avatarkit.recon import bald_discs, visibility

    floor = bald_discs.GRAZING / 2
    monkeypatch.setattr(visibility, "MIN_FACING", floor)
    w = bald_discs.photo_weight(np.array([floor, (floor + bald_discs.GRAZING) / 2, bald_discs.GRAZING]))
    np.testing.assert_allclose(w, [0.0, 0.5, 1.0])
