"""A synthetic subject not made of our own Gaussians: the template head mesh with a procedural
texture and a separate hair-cap mesh, drawn by a z-buffer mesh rasteriser
(`synthetic.mesh_raster`) with Lambert shading. The turning video of the sample avatar
(`synthetic.turning_video`) renders an avatar we built with our own splatting, so a build is
partly graded on producing its own kind of output; this subject is made and drawn another way.

Geometry: the template's rest mesh (shape 0; eyeballs and the mouth band included) posed by a
clip (the head model's LBS, as the tracker sees it); the hair cap is the template's scalp
triangles pushed out along the posed vertex normals by `CAP_THICKNESS` (thicker on the crown),
a second mesh over the first.

Texture (evaluated per pixel at the interpolated rest-frame point, so it is as sharp as the
image allows, not as the mesh): skin `SKIN` with a smooth 3D variation and warmer cheeks;
brows (an arch above each eye joint), lips and the mouth band from the template's regions;
eyeballs white with an iris and a pupil around the eye's forward axis; the hair cap `HAIR` with
strand-like streaks running from the crown down. Shading: ambient + Lambert from a light fixed to
the head (`LIGHT`), so the subject looks the same from every camera for a given head pose: a
Gaussian avatar's colours are view-independent, and the held-out views compare geometry and
colour, not relighting.

`turning_video` renders it with `turning_video.turning_clip` from the tracker's camera;
`view_psnr` compares renders of a built avatar at rest with this subject at rest from the
comparison cameras of `turning_video.novel_view_psnr` (front, three-quarter, profile).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avatarkit.head.regions import vertex_normals
from avatarkit.render.camera import Camera

SKIN = (0.86, 0.66, 0.54)
CHEEK = (0.88, 0.55, 0.50)
LIPS = (0.66, 0.30, 0.32)
MOUTH = (0.25, 0.08, 0.08)
BROW = (0.30, 0.20, 0.14)
SCLERA = (0.92, 0.91, 0.88)
IRIS = (0.36, 0.26, 0.16)
PUPIL = (0.04, 0.03, 0.03)
HAIR = (0.36, 0.24, 0.15)
#: metres the hair cap stands off the scalp: (at the sides, added on the crown)
CAP_THICKNESS = (0.006, 0.010)
#: light direction in the head frame (normalised), and the ambient share
LIGHT = (0.35, 0.55, 0.75)
AMBIENT = 0.45
#: supersampling per axis (box-filtered)
SUPERSAMPLE = 2


def _noise(points: np.ndarray, seed: int, wavelength: float, waves: int = 6) -> np.ndarray:
    """A smooth field in about [-1, 1]: a sum of plane waves with fixed random directions."""
    rng = np.random.default_rng(seed)
    k = rng.normal(size=(waves, 3))
    k *= (2 * np.pi / wavelength) / np.linalg.norm(k, axis=1, keepdims=True)
    return np.sin(points @ k.T + rng.uniform(0, 2 * np.pi, waves)).sum(axis=1) / np.sqrt(waves / 2)


@dataclass(eq=False)
class MeshHead:
    """The mesh subject (module docstring): model (the template `HeadModel`); rest (V, 3);
    faces (F, 3) of the head; cap (K,) the scalp vertices the cap is made of and cap_faces
    (G, 3) indexing into them; regions (V, 3) float: the template's eyes, lips and mouth-band
    vertex masks."""

    model: object
    rest: np.ndarray
    faces: np.ndarray
    cap: np.ndarray
    cap_faces: np.ndarray
    regions: np.ndarray

    @classmethod
    def make(cls) -> "MeshHead":
        from avatarkit.avatar import _rest_vertices
        from avatarkit.head.model import HeadModel

        model = HeadModel.template()
        rest = np.asarray(_rest_vertices(model, np.zeros(model.num_shape, np.float32)), np.float64)
        faces = np.asarray(model.faces, np.int64)
        scalp = model.region_mask("scalp")
        cap_tri = faces[scalp[faces].all(axis=1)]
        cap = np.unique(cap_tri)
        remap = np.full(len(rest), -1, np.int64)
        remap[cap] = np.arange(len(cap))
        regions = np.stack([model.region_mask(r).astype(np.float64) for r in ("eyes", "lips", "mouth_interior")],
                           axis=1)
        return cls(model, rest, faces, cap, remap[cap_tri], regions)

    def posed(self, clip, frame: int) -> np.ndarray:
        """(V, 3) head vertices at `frame` of a MotionClip (shape 0)."""
        from avatarkit.head.model import HeadParams

        params = HeadParams.from_clip(clip, frames=[frame])
        params.shape = np.zeros(self.model.num_shape, np.float32)
        return np.asarray(self.model.forward(params)[0][0], np.float64)

    def _cap_offset(self) -> np.ndarray:
        """(K,) metres each cap vertex stands off the scalp (rest frame: up = +Y)."""
        n = vertex_normals(self.rest, self.faces)[self.cap]
        return CAP_THICKNESS[0] + CAP_THICKNESS[1] * np.clip(n[:, 1], 0, 1)

    def meshes(self, vertices: np.ndarray):
        """Head + cap as one mesh for posed head vertices (V, 3): (points (V+K, 3), faces,
        attributes (V+K, 11): rest point, rest normal, hair, eyes, lips, mouth, 1)."""
        normals = vertex_normals(vertices, self.faces)
        cap_pts = vertices[self.cap] + self._cap_offset()[:, None] * normals[self.cap]
        rest_n = vertex_normals(self.rest, self.faces)
        rest_cap = self.rest[self.cap] + self._cap_offset()[:, None] * rest_n[self.cap]
        V, K = len(self.rest), len(self.cap)
        attrs = np.zeros((V + K, 11))
        attrs[:V, 0:3], attrs[V:, 0:3] = self.rest, rest_cap
        attrs[:V, 3:6], attrs[V:, 3:6] = rest_n, rest_n[self.cap]
        attrs[V:, 6] = 1.0
        attrs[:V, 7:10] = self.regions
        attrs[:, 10] = 1.0
        return np.concatenate([vertices, cap_pts]), np.concatenate([self.faces, self.cap_faces + V]), attrs

    def shade(self, attrs: np.ndarray) -> np.ndarray:
        """(P, 3) colours in [0, 1] of drawn pixels' interpolated attributes (P, 11)."""
        p, n = attrs[:, 0:3], attrs[:, 3:6]
        n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        hair, eyes, lips, mouth = (attrs[:, k] > 0.5 for k in (6, 7, 8, 9))
        rgb = np.broadcast_to(np.asarray(SKIN), (len(p), 3)) * (1 + 0.05 * _noise(p, 11, 0.07))[:, None]
        joints = np.asarray(self.model.rest_joints()[0], np.float64)
        eye_l, eye_r = joints[3], joints[4]
        u = float(np.linalg.norm(eye_l - eye_r))
        for eye in (eye_l, eye_r):
            # a warm cheek below and outside each eye
            c = eye + np.array([0.25 * np.sign(eye[0]) * u, -0.75 * u, 0.0])
            w = np.exp(-np.sum((p[:, :2] - c[:2]) ** 2, axis=1) / (2 * (0.28 * u) ** 2)) * (p[:, 2] > eye[2] - 0.3 * u)
            rgb = rgb * (1 - 0.5 * w[:, None]) + 0.5 * w[:, None] * np.asarray(CHEEK)
            # brows: a band arching 0.32..0.45 u above the eye joint over +-0.45 u sideways
            dx = (p[:, 0] - eye[0]) / (0.45 * u)
            lift = (p[:, 1] - eye[1]) / u - (0.32 + 0.1 * (1 - dx ** 2))
            brow = (np.abs(dx) < 1) & (lift > 0) & (lift < 0.06 + 0.07 * (1 - dx ** 2)) & (p[:, 2] > eye[2]) & ~eyes
            rgb[brow] = BROW
        rgb[lips] = LIPS
        rgb[mouth] = MOUTH
        if eyes.any():
            rgb[eyes] = SCLERA
            for eye in (eye_l, eye_r):
                d = p - eye
                cos = d[:, 2] / np.maximum(np.linalg.norm(d, axis=1), 1e-12)
                near = eyes & (np.linalg.norm(d, axis=1) < 0.6 * u)
                rgb[near & (cos > np.cos(np.radians(22)))] = IRIS
                rgb[near & (cos > np.cos(np.radians(9)))] = PUPIL
        if hair.any():
            # streaks along the strands (meridians from the crown), their phase wandering a little
            az = np.arctan2(p[hair, 0], p[hair, 2])
            streak = 0.16 * np.sin(48 * az + 3 * _noise(p[hair], 5, 0.05)) + 0.06 * _noise(p[hair], 7, 0.02)
            rgb[hair] = np.asarray(HAIR) * (1 + streak)[:, None]
        light = np.asarray(LIGHT) / np.linalg.norm(LIGHT)
        lambert = AMBIENT + (1 - AMBIENT) * np.clip(n @ light, 0, 1)
        return np.clip(rgb * lambert[:, None], 0, 1)

    def render(self, camera: Camera, vertices: np.ndarray | None = None, background=(1.0, 1.0, 1.0)):
        """(rgb (H, W, 3) float in [0, 1] on `background`, alpha (H, W) coverage) of the head
        posed as `vertices` (default: rest), `SUPERSAMPLE`d."""
        from avatarkit.synthetic.mesh_raster import downsample, rasterise

        k = SUPERSAMPLE
        pts, faces, attrs = self.meshes(self.rest if vertices is None else np.asarray(vertices, np.float64))
        r = rasterise(pts, faces, attrs, camera.with_size(camera.width * k, camera.height * k))
        img = np.broadcast_to(np.asarray(background, np.float64), r.covered.shape + (3,)).copy()
        img[r.covered] = self.shade(r.attributes[r.covered])
        return downsample(img, k), downsample(r.covered.astype(np.float64), k)

    def hair_coverage(self, camera: Camera, vertices: np.ndarray | None = None) -> np.ndarray:
        """(H, W) float in [0, 1]: the share of each pixel the hair cap covers (as `render`
        sees it, `SUPERSAMPLE`d): the segmentation tests' and benchmark's hair truth."""
        from avatarkit.synthetic.mesh_raster import downsample, rasterise

        k = SUPERSAMPLE
        pts, faces, attrs = self.meshes(self.rest if vertices is None else np.asarray(vertices, np.float64))
        r = rasterise(pts, faces, attrs, camera.with_size(camera.width * k, camera.height * k))
        return downsample((r.covered & (r.attributes[..., 6] > 0.5)).astype(np.float64), k)

    def bounds(self):
        """(lo, hi) of the rest head: what the comparison cameras frame."""
        return self.rest.min(axis=0), self.rest.max(axis=0)


def turning_video(subject: MeshHead, path, size: int = 192, frames: int = 32, distance: float = 0.5,
                  clip=None, background=(1.0, 1.0, 1.0)):
    """The subject turning its head (`turning_video.turning_clip`), rendered from the tracker's
    camera (`head_video.head_video_camera`) to an H.264 video at `path`, over `background` (an
    (r, g, b) colour or a (size, size, 3) image, `synthetic.walls`); returns the clip."""
    from avatarkit.export.images import to_uint8
    from avatarkit.export.video import write_video
    from avatarkit.synthetic.head_video import head_video_camera
    from avatarkit.synthetic.turning_video import turning_clip

    clip = clip or turning_clip(frames)
    camera = head_video_camera(size, distance=distance)
    if np.ndim(background) == 3:
        # an (H, W, 3) wall image (`synthetic.walls`) under a render made over black
        from avatarkit.synthetic.walls import over_wall

        frames_rgb = (over_wall(*subject.render(camera, subject.posed(clip, i), (0.0, 0.0, 0.0)), background)
                      for i in range(clip.n_frames))
    else:
        frames_rgb = (subject.render(camera, subject.posed(clip, i), background)[0] for i in range(clip.n_frames))
    write_video(path, (to_uint8(f) for f in frames_rgb), fps=clip.fps, crf=12)
    return clip


def view_psnr(built, subject: MeshHead, size: int = 192, azimuths=None,
              background=(1.0, 1.0, 1.0)) -> dict[float, float]:
    """Azimuth (degrees) -> PSNR (dB) of `built` rendered at rest against the subject at rest,
    over the pixels either covers (alpha > 0.5), both on `background`; the cameras frame the
    subject's rest head from `turning_video.VIEW_AZIMUTHS` as `novel_view_psnr` does."""
    from avatarkit.recon.assemble import psnr
    from avatarkit.render import render
    from avatarkit.render.views import frame_camera
    from avatarkit.synthetic.turning_video import VIEW_AZIMUTHS

    ours = built.rest_gaussians()
    out = {}
    for az in VIEW_AZIMUTHS if azimuths is None else azimuths:
        cam = frame_camera(subject.bounds(), az, 0.0, width=size, height=size)
        rgb, alpha = subject.render(cam, background=background)
        b = render(ours, cam, background)
        mask = (alpha > 0.5) | (b.alpha > 0.5)
        out[float(az)] = float(psnr(b.rgb, rgb.astype(np.float32), mask))
    return out


__all__ = ["MeshHead", "turning_video", "view_psnr"]
