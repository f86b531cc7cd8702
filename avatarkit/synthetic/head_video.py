"""Videos of the template head driven by a known clip: ground truth for the tracker's tests and
benchmark, and for the self-reenactment evaluation's end-to-end check.

The head is the built-in template with `synthetic.sample_avatar.make_bald` skin discs bound to
its triangles (`rig.TriangleBinding`), posed per frame by the clip (LBS) and rendered with our
CPU renderer from a fixed camera: the camera a tracker would report for a head of that size at
`distance` metres with the portrait lens of `recon.fit.portrait_focal`. `light` and `mouth`
make the head look more like a person to the face mesh (`synthetic.shading`): Lambert shading
that moves with the pose, and a dark mouth interior when the jaw opens.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import numpy as np

from avatarkit.render.camera import Camera

_C = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True, eq=False)
class SyntheticFrame:
    index: int
    time: float
    rgb: np.ndarray     # (H, W, 3) uint8


def head_video_camera(size: int, distance: float = 0.6, height: float = 0.05) -> Camera:
    """A camera on +Z looking at the head (-Z), `distance` metres from the point `height` above
    the template's origin (the neck joint: the eyes sit ~5 cm above it)."""
    from avatarkit.recon.fit import portrait_focal

    f = portrait_focal(size, size)
    w2c = np.eye(4)
    w2c[:3, :3] = _C
    w2c[:3, 3] = _C @ np.array([0.0, -height, -distance])
    return Camera(f, f, size / 2, size / 2, size, size, w2c)


class HeadVideo:
    """Frames of the template head moved by `clip` (a MotionClip), seen by `camera`.

    light: None (flat colours) or a direction toward the light in the camera's frame
    (`shading.LIGHT`); ambient: the unlit share; mouth: add the dark mouth interior."""

    def __init__(self, clip, camera: Camera, n_gaussians: int = 30000, seed: int = 0,
                 background=(0.47, 0.59, 0.73), light=None, ambient: float | None = None, mouth: bool = False):
        from avatarkit.head.model import HeadModel, HeadParams
        from avatarkit.rig.binding import TriangleBinding
        from avatarkit.synthetic import shading
        from avatarkit.synthetic.sample_avatar import make_bald

        self.model = HeadModel.template()
        self.clip, self.camera, self.background = clip, camera, background
        self.shape = np.zeros(self.model.num_shape, np.float32)
        rest = self.model.forward(HeadParams(shape=self.shape, expr=np.zeros((1, self.model.num_expr))))[0][0]
        bald = make_bald(self.model, rest, n_gaussians, seed)
        self.binding = TriangleBinding.bind(bald, rest, self.model.faces,
                                            face_ids=bald.extras["binding"].astype(np.int64))
        # the mouth interior: each Gaussian's host triangle, the triangles' rest areas, and
        # which triangles are the lips / mouth band
        self.host = bald.extras["binding"].astype(np.int64)
        self.rest_area = shading.triangle_areas(rest, self.model.faces)
        self.mouth = shading.mouth_faces(self.model) if mouth else None
        self.to_light = None if light is None else shading.light_in_world(camera, light)
        self.ambient = shading.AMBIENT if ambient is None else float(ambient)

    def __len__(self) -> int:
        return self.clip.n_frames

    def vertices(self, i: int) -> np.ndarray:
        from avatarkit.head.model import HeadParams

        params = HeadParams.from_clip(self.clip, frames=[i])
        params.shape = self.shape
        return self.model.forward(params)[0][0]

    def frame(self, i: int) -> SyntheticFrame:
        from avatarkit.export.images import to_uint8
        from avatarkit.render import render
        from avatarkit.synthetic import shading

        v = self.vertices(i)
        g = self.binding.to_world(v)
        if self.mouth is not None:
            opening = shading.mouth_opening(self.rest_area, shading.triangle_areas(v, self.model.faces), self.mouth)
            g = g.with_colors(shading.darken_mouth(g.colors, opening[self.host]))
        if self.to_light is not None:
            g = shading.shade_gaussians(g, v, self.model.faces, self.to_light, self.ambient)
        r = render(g, self.camera, background=self.background)
        return SyntheticFrame(i, i / self.clip.fps, to_uint8(r.rgb))

    def frames(self) -> Iterator[SyntheticFrame]:
        for i in range(len(self)):
            yield self.frame(i)


def avatar_video(avatar, clip, camera: Camera, background=(1.0, 1.0, 1.0), static_hair: bool = True
                 ) -> Iterator[SyntheticFrame]:
    """Frames of a baked avatar (bald + hair) driven by `clip`, rendered by `camera`: a video
    whose motion and camera are known exactly (what `avatarkit evaluate` and the tracker's
    benchmark compare against)."""
    from avatarkit.bake import BakeConfig, bake
    from avatarkit.export.images import to_uint8
    from avatarkit.render import render
    from avatarkit.sim.config import SimConfig
    from avatarkit.synthetic.walls import over_wall

    config = BakeConfig(sim=SimConfig(static=static_hair))
    static, frames = bake(avatar, clip, config)
    # background: an (r, g, b) colour, or an (H, W, 3) image (`synthetic.walls`) put under a
    # render made over black
    wall = np.asarray(background, np.float32) if np.ndim(background) == 3 else None
    for frame in frames:
        r = render(frame.person(static, avatar.has_hair), camera, (0.0, 0.0, 0.0) if wall is not None else background)
        rgb = r.rgb if wall is None else over_wall(r.rgb, r.alpha, wall)
        yield SyntheticFrame(frame.index, frame.index / clip.fps, to_uint8(rgb))
