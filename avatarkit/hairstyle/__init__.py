"""Hairstyles move between avatars: hair relative to the scalp, re-seated on another head,
cleaned of the source's skin, pushed outside the head and re-rigged (`transfer_hair`); several
hairstyles on one head in a contact sheet (`hair_grid`)."""
from avatarkit.hairstyle.cleanup import SkinCleanup, skin_in_hair
from avatarkit.hairstyle.grid import VIEWS, HairGrid, hair_grid, parse_views
from avatarkit.hairstyle.relative import NEIGHBOURS, ScalpHair, check_same_topology, scalp_faces
from avatarkit.hairstyle.transfer import (CAGE_VERTICES, MARGIN, Reseated, TransferReport,
                                          reseat_hair, transfer_hair)

__all__ = ["CAGE_VERTICES", "MARGIN", "NEIGHBOURS", "VIEWS", "HairGrid", "Reseated", "ScalpHair",
           "SkinCleanup", "TransferReport", "check_same_topology", "hair_grid", "parse_views",
           "reseat_hair", "scalp_faces", "skin_in_hair", "transfer_hair"]
