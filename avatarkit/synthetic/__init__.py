"""Procedural test content: deterministic (seeded), real-sized stand-ins for reconstructed data."""
from avatarkit.synthetic.hair import HAIR_STYLES, HeadEllipsoid, hair_strands, make_hair

__all__ = ["HAIR_STYLES", "HeadEllipsoid", "hair_strands", "make_hair"]
