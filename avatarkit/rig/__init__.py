"""Rigging: triangle frames and Gaussians bound to mesh triangles (GaussianAvatars-style)."""
from avatarkit.rig.binding import PosedGaussians, TriangleBinding, local_to_world, world_to_local
from avatarkit.rig.frames import degenerate_faces, frames_and_degenerate, points_on_triangles, triangle_frames
from avatarkit.rig.nearest import nearest_faces, point_triangle_distance

__all__ = ["PosedGaussians", "TriangleBinding", "degenerate_faces", "frames_and_degenerate",
           "local_to_world", "nearest_faces", "point_triangle_distance", "points_on_triangles", "triangle_frames",
           "world_to_local"]
