"""Parametric heads: `HeadModel` (FLAME-compatible), `HeadParams`, LBS, the built-in procedural
template head and a chumpy-free loader for a user's own FLAME model file."""
from avatarkit.head.io import load_head_model, load_npz, save_npz
from avatarkit.head.model import FLAME_PARENTS, JOINT_NAMES, HeadModel, HeadParams


def load_template() -> HeadModel:
    """The built-in procedural template head (see `avatarkit.head.template`)."""
    from avatarkit.head.template import load_template as _load
    return _load()


def load_flame(path, num_shape: int = 300) -> HeadModel:
    """A user's FLAME 2020/2023 pickle, read without chumpy (see `avatarkit.head.flame`)."""
    from avatarkit.head.flame import load_flame as _load
    return _load(path, num_shape=num_shape)


__all__ = ["HeadModel", "HeadParams", "JOINT_NAMES", "FLAME_PARENTS", "load_template", "load_flame",
           "load_head_model", "load_npz", "save_npz"]
