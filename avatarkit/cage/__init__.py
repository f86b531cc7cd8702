"""Hair cage: a closed cage around Gaussians, mean value coordinates, deformation through it.

    cage = build_cage(hair)                         # <= 500 vertices, checked guarantees
    deformer = CageDeformer.build(hair, cage)       # MVC weights of 2 points per Gaussian
    moved = deformer.deform(new_cage_vertices)      # one (P, C) x (C, 3) product per frame
"""
from avatarkit.cage.build import build_cage
from avatarkit.cage.deform import CageDeformer, CageWeights, load_weights, save_weights
from avatarkit.cage.inside import clipped_depth, winding_numbers, winding_numbers_reference
from avatarkit.cage.mesh import Cage, CageCheck, check_cage, load_cage, save_cage
from avatarkit.cage.mvc import (SparseError, mvc_weights, mvc_weights_reference, sparse_apply,
                                sparse_error, sparsify)
from avatarkit.cage.points import AXIS_SIGMA, cage_points, deformation_points

__all__ = [
    "AXIS_SIGMA", "Cage", "CageCheck", "CageDeformer", "CageWeights", "SparseError", "build_cage",
    "cage_points", "check_cage", "clipped_depth", "deformation_points", "load_cage", "load_weights",
    "mvc_weights", "mvc_weights_reference", "save_cage", "save_weights", "sparse_apply",
    "sparse_error", "sparsify", "winding_numbers", "winding_numbers_reference",
]
