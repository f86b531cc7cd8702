"""CPU splat renderer: cameras, the 3DGS image formation (fast Taichi path) and view helpers.

    from avatarkit.render import render, frame_camera
    result = render(gaussians, frame_camera(gaussians, azimuth_deg=30), background=(1, 1, 1))
    result.rgb  # (H, W, 3) float32

Taichi is imported only when the first frame is rendered.
"""
from avatarkit.render.camera import Camera
from avatarkit.render.pipeline import (Projection, RenderResult, TileBins, bin_gaussians,
                                       project_gaussians, rasterize, render, sh_colors)
from avatarkit.render.views import frame_camera, framing, scene_bounds, turntable_cameras

__all__ = ["Camera", "Projection", "RenderResult", "TileBins", "bin_gaussians", "frame_camera",
           "framing", "project_gaussians", "rasterize", "render", "scene_bounds", "sh_colors",
           "turntable_cameras"]
