"""Parametric heads: `HeadModel` (FLAME-compatible), `HeadParams`, LBS, the built-in procedural
template head and a chumpy-free loader for a user's own FLAME model file.

Layers, each importing only those above it: `joints`, `lbs`, `regions`, `sdf`, `remesh` ->
`template` (the template head's arrays) -> `model` (HeadModel, HeadParams, load_template) ->
`flame`, `npz` (files) -> `io` (load_head_model by suffix); `ref` (HeadRef: which head an avatar
rides). `sdf_grid` (HeadSDF: a head mesh's signed distance grid) stands alone.
"""
from avatarkit.head.flame import load_flame
from avatarkit.head.io import load_head_model
from avatarkit.head.model import FLAME_PARENTS, JOINT_NAMES, HeadModel, HeadParams, load_template
from avatarkit.head.npz import load_npz, save_npz

__all__ = ["HeadModel", "HeadParams", "JOINT_NAMES", "FLAME_PARENTS", "load_template", "load_flame",
           "load_head_model", "load_npz", "save_npz"]
