"""Gaussian splats in memory (`GaussianSet`) and their file formats."""
from avatarkit.gaussians.gaussian_set import GaussianSet

__all__ = ["GaussianSet"]
