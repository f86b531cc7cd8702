"""Load a user's own FLAME model file (`generic_model.pkl`, FLAME 2020; `flame2023.pkl`) without chumpy.

The official pickles were written under Python 2 with chumpy `Ch` objects for some arrays and a
scipy.sparse `J_regressor`. We unpickle with `encoding="latin1"` and a restricted
`Unpickler.find_class`: numpy and scipy.sparse classes load as themselves, every `chumpy.*`
class loads as `_ChStub` (which keeps whatever state it is given; the array is found in it
afterwards), and anything else is refused, so a model file cannot run code.

Keys used: v_template (V,3), f (F,3), shapedirs (V,3,300+E), posedirs (V,3,36),
J_regressor (5,V) sparse or dense, weights (V,5), kintree_table (2,5).
FLAME ships its region masks separately (FLAME_masks.pkl), so regions are derived from the
geometry with the same rules as the template (`avatarkit.head.regions`).
"""
from __future__ import annotations

import os
import pickle
from pathlib import Path

import numpy as np

from avatarkit.errors import FormatError, InputError
from avatarkit.fileio import file_sha256
from avatarkit.head.model import HeadModel
from avatarkit.head.regions import derive_regions

#: identity components FLAME puts before its expression components in `shapedirs`
FLAME_NUM_SHAPE = 300

_SAFE_BUILTINS = {"object", "set", "frozenset", "complex", "slice", "tuple", "list", "dict",
                  "int", "float", "bytearray", "bool", "str", "bytes"}


class _ChStub:
    """Stands in for every chumpy class. `Ch` keeps its value in state['x']; chumpy operators
    (`chumpy.ch_ops.*`, `chumpy.reordering.*`) keep their operands under other keys."""

    args: tuple = ()
    state = None

    def __new__(cls, *args, **kwargs):
        obj = object.__new__(cls)
        obj.args = args
        return obj

    def __init__(self, *args, **kwargs):
        pass

    def __setstate__(self, state):
        self.state = state


def _arrays_in(obj, depth: int = 0):
    """Every ndarray reachable from a chumpy stub's state (depth-limited)."""
    if isinstance(obj, np.ndarray):
        yield obj
    elif isinstance(obj, _ChStub) and depth < 16:
        value = _to_array(obj, depth + 1)
        if isinstance(value, np.ndarray):
            yield value
    elif isinstance(obj, (list, tuple)) and depth < 16:
        for item in obj:
            yield from _arrays_in(item, depth + 1)


def _to_array(obj, depth: int = 0):
    """The ndarray a chumpy stub stands for: its state['x'] (a `Ch`), else the largest array in
    its state (an operator node's operand), else obj itself when it is not a stub."""
    if not isinstance(obj, _ChStub):
        return obj
    state = obj.state
    if isinstance(state, tuple) and len(state) == 2 and isinstance(state[0], dict):
        state = {**state[0], **(state[1] or {})}
    if isinstance(state, dict) and "x" in state:
        return _to_array(state["x"], depth + 1)
    values = list(state.values()) if isinstance(state, dict) else []
    found = [a for v in values + list(obj.args) for a in _arrays_in(v, depth)]
    return max(found, key=lambda a: a.size) if found else None


class _FlameUnpickler(pickle.Unpickler):
    def find_class(self, module, name):
        if module == "chumpy" or module.startswith("chumpy."):
            return _ChStub
        if module in ("copy_reg", "copyreg") and name in ("_reconstructor", "__newobj__"):
            import copyreg
            return getattr(copyreg, name)
        if module in ("__builtin__", "builtins") and name in _SAFE_BUILTINS:
            import builtins
            return getattr(builtins, name)
        if module == "_codecs" and name == "encode":
            import codecs
            return codecs.encode
        if module == "collections" and name == "OrderedDict":
            import collections
            return collections.OrderedDict
        if module == "numpy" or module.startswith("numpy."):
            # numpy 2 moved numpy.core to numpy._core; old pickles name the former.
            if module.startswith("numpy.core"):
                module = "numpy._core" + module[len("numpy.core"):]
            return super().find_class(module, name)
        if module == "scipy.sparse" or module.startswith("scipy.sparse."):
            import scipy.sparse
            # Old files name private modules (scipy.sparse.csc) that newer scipy deprecates or
            # drops; the public class of the same name is the same thing.
            if hasattr(scipy.sparse, name):
                return getattr(scipy.sparse, name)
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"refusing to load {module}.{name} (not part of a FLAME model)")


def _read_pickle(path: Path) -> dict:
    try:
        with open(path, "rb") as fh:
            data = _FlameUnpickler(fh, encoding="latin1").load()
    except OSError as e:
        raise InputError(f"cannot read FLAME model: {e.strerror or e}", path) from None
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError, ImportError,
            IndexError, KeyError, UnicodeDecodeError) as e:
        raise FormatError(f"not a readable FLAME model pickle ({type(e).__name__}: {e})", path) from None
    if not isinstance(data, dict):
        raise FormatError(f"not a FLAME model: the pickle holds a {type(data).__name__}, not a dict", path)
    return data


def _array(data: dict, key: str, path: Path, ndim: int, dtype=np.float32, sparse_ok: bool = False):
    if key not in data:
        raise FormatError(f"missing key {key!r}", path)
    value = _to_array(data[key])
    if sparse_ok and hasattr(value, "toarray") and hasattr(value, "shape"):
        return value
    try:
        a = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError):
        raise FormatError(f"key {key!r} is not a numeric array (got {type(data[key]).__name__})", path) from None
    if a.ndim != ndim:
        raise FormatError(f"key {key!r} must have {ndim} dimensions, got shape {a.shape}", path)
    if not np.all(np.isfinite(a)):
        raise FormatError(f"key {key!r} contains NaN or infinite values", path)
    return a


def load_flame(path: str | os.PathLike, num_shape: int | None = None) -> HeadModel:
    """Read a FLAME 2020/2023 model pickle into a HeadModel (no chumpy needed).

    `shapedirs` (V, 3, 400) is split into `num_shape` identity components and the rest as
    expression components. Errors (unreadable file, missing key, wrong shape) are FormatError
    naming the file and the key.
    """
    num_shape = FLAME_NUM_SHAPE if num_shape is None else num_shape
    path = Path(path)
    if not path.is_file():
        raise InputError("FLAME model file not found", path)
    data = _read_pickle(path)
    v_template = _array(data, "v_template", path, 2)
    V = len(v_template)
    if v_template.shape[1] != 3 or V < 4:
        raise FormatError(f"key 'v_template' must have shape (V, 3), got {v_template.shape}", path)
    faces = _array(data, "f", path, 2, dtype=np.int64)
    if faces.shape[1] != 3 or faces.min(initial=0) < 0 or faces.max(initial=0) >= V:
        raise FormatError(f"key 'f' must be (F, 3) vertex indices below {V}, got shape {faces.shape}", path)
    shapedirs = _array(data, "shapedirs", path, 3)
    if shapedirs.shape[:2] != (V, 3):
        raise FormatError(f"key 'shapedirs' must have shape ({V}, 3, k), got {shapedirs.shape}", path)
    if shapedirs.shape[2] < num_shape:
        raise FormatError(f"key 'shapedirs' has {shapedirs.shape[2]} components, expected at least "
                          f"{num_shape} identity components (+ expression)", path)
    kintree = _array(data, "kintree_table", path, 2, dtype=np.int64)
    if kintree.shape != (2, 5):
        raise FormatError(f"key 'kintree_table' must have shape (2, 5), got {kintree.shape}", path)
    J = kintree.shape[1]
    weights = _array(data, "weights", path, 2)
    if weights.shape != (V, J):
        raise FormatError(f"key 'weights' must have shape ({V}, {J}), got {weights.shape}", path)
    J_regressor = _array(data, "J_regressor", path, 2, sparse_ok=True)
    if tuple(J_regressor.shape) != (J, V):
        raise FormatError(f"key 'J_regressor' must have shape ({J}, {V}), got {tuple(J_regressor.shape)}", path)
    if hasattr(J_regressor, "toarray"):
        import scipy.sparse
        J_regressor = scipy.sparse.csr_matrix(J_regressor, dtype=np.float32)
    posedirs = None
    if "posedirs" in data:
        pd = _array(data, "posedirs", path, 3)
        if pd.shape != (V, 3, 9 * (J - 1)):
            raise FormatError(f"key 'posedirs' must have shape ({V}, 3, {9 * (J - 1)}), got {pd.shape}", path)
        posedirs = pd.reshape(V * 3, -1).T  # (36, V*3), as FLAME's own code reshapes it
    # kintree_table[0] holds parents (root's is a huge sentinel), kintree_table[1] the joint ids.
    ids = kintree[1]
    if sorted(ids.tolist()) != list(range(J)):
        raise FormatError(f"key 'kintree_table' row 1 must list joints 0..{J - 1}, got {ids.tolist()}", path)
    parents = np.full(J, -1, dtype=np.int64)
    id_to_col = {int(j): c for c, j in enumerate(ids)}
    for c, j in enumerate(ids):
        p = int(kintree[0, c])
        parents[j] = p if p in id_to_col and p != j else -1
    if parents.tolist() != [-1, 0, 1, 1, 1]:
        raise FormatError(f"key 'kintree_table' does not have FLAME's joint layout "
                          f"(parents {parents.tolist()}, expected [-1, 0, 1, 1, 1])", path)
    sums = weights.sum(1)
    if np.abs(sums - 1).max() > 1e-3:
        raise FormatError(f"key 'weights' rows must sum to 1 (worst {sums[np.abs(sums - 1).argmax()]:.4f})", path)
    model = HeadModel(faces=faces, v_template=v_template, shapedirs=shapedirs[:, :, :num_shape],
                      exprdirs=shapedirs[:, :, num_shape:], posedirs=posedirs, J_regressor=J_regressor,
                      kintree_parents=parents, weights=weights,
                      name="flame", source=f"{path.resolve()} sha256:{file_sha256(path)}")
    model.regions = derive_regions(model)
    return model


__all__ = ["load_flame", "FLAME_NUM_SHAPE"]
