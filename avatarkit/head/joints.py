"""FLAME's joint layout, shared by the head model, its loaders and the template head.

0 root/global, 1 neck, 2 jaw, 3 left eye, 4 right eye (DESIGN.md); parents [-1, 0, 1, 1, 1].
"""
from __future__ import annotations

import numpy as np

JOINT_NAMES = ("root", "neck", "jaw", "left_eye", "right_eye")
FLAME_PARENTS = np.array([-1, 0, 1, 1, 1], dtype=np.int64)

__all__ = ["JOINT_NAMES", "FLAME_PARENTS"]
