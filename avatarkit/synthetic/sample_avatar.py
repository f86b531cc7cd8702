"""The sample avatar, made in code: the built-in template head, bald Gaussians on its surface,
procedural hair grown from its scalp, the hair's cage and rig. Bake works with it before (and
without) `avatarkit build`.

Bald Gaussians: points sampled uniformly by area on the template's triangles (eyeballs and
the mouth band included), each a flat disc lying in its triangle's plane (its thin axis, scale
index 1, along the face normal), sized so neighbours overlap. Colours: skin with a smooth
low-frequency variation and a little per-splat noise; lips redder, the mouth band dark, brows
darker (an arch above each eye, found from the eye joints), eyeballs white with an iris and a
pupil on the eye's forward axis. Bound to the triangle it was sampled on (`binding` extra).

Hair: `synthetic.head_hair.make_test_avatar` (strands grown from the template's scalp region,
pushed outside the head, and a cage of ~500 vertices around them). Deterministic for a seed.
"""
from __future__ import annotations

import numpy as np

from avatarkit.errors import InputError
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.rig.frames import points_on_triangles

SKIN = (0.80, 0.60, 0.50)
LIPS = (0.72, 0.36, 0.36)
MOUTH = (0.30, 0.10, 0.10)
BROW = (0.22, 0.15, 0.11)
SCLERA = (0.93, 0.92, 0.89)
IRIS = (0.24, 0.36, 0.52)
PUPIL = (0.03, 0.03, 0.03)
#: disc radius = this x the radius that would tile the surface exactly (overlap hides seams)
COVERAGE = 1.6
#: disc thickness relative to its radius
FLATNESS = 0.12
#: the pupil's half-angle around the eye's forward axis, degrees (the iris region reaches 35)
PUPIL_DEG = 9.0
#: hair asked of the generator per hair Gaussian wanted: strands whose root misses the scalp
#: are dropped (about 7% for long hair), the surplus is cut off the last strand
HAIR_SURPLUS = 1.12


def _face_mask(head, region: str, faces: np.ndarray) -> np.ndarray:
    """(F,) bool: faces with at least two vertices in `region` (False if the model lacks it)."""
    if region not in head.regions:
        return np.zeros(len(faces), bool)
    return head.region_mask(region)[faces].sum(axis=1) >= 2


def sample_surface(vertices: np.ndarray, faces: np.ndarray, n: int, rng: np.random.Generator
                   ) -> tuple[np.ndarray, np.ndarray]:
    """n points uniformly by area on the mesh -> (face ids (n,) int32, points (n, 3) float64)."""
    tri = np.asarray(vertices, np.float64)[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    if not area.sum() > 0:
        raise InputError("the head mesh has no area to put Gaussians on")
    ids = rng.choice(len(faces), size=n, p=area / area.sum())
    points = points_on_triangles(tri[ids], rng)
    return ids.astype(np.int32), points


def _smooth_noise(points: np.ndarray, rng: np.random.Generator, waves: int = 6,
                  wavelength: float = 0.04) -> np.ndarray:
    """A smooth scalar field in about [-1, 1] at points (n, 3): a sum of random plane waves."""
    k = rng.normal(size=(waves, 3))
    k *= (2 * np.pi / wavelength) / np.linalg.norm(k, axis=1, keepdims=True)
    phase = rng.uniform(0, 2 * np.pi, waves)
    return np.sin(points @ k.T + phase).sum(axis=1) / np.sqrt(waves / 2)


def bald_colors(head, vertices: np.ndarray, face_ids: np.ndarray, points: np.ndarray,
                rng: np.random.Generator) -> np.ndarray:
    """RGB (n, 3) in [0, 1] for bald Gaussians at points (n, 3) on faces face_ids (n,)."""
    faces = head.faces
    rgb = np.broadcast_to(np.asarray(SKIN), (len(points), 3)).copy()
    rgb *= 1 + 0.03 * _smooth_noise(points, rng, wavelength=0.06)[:, None]
    rgb[_face_mask(head, "lips", faces)[face_ids]] = LIPS
    rgb[_face_mask(head, "mouth_interior", faces)[face_ids]] = MOUTH

    joints = head.rest_joints()[0].astype(np.float64)
    eye_l, eye_r = joints[3], joints[4]
    u = float(np.linalg.norm(eye_l - eye_r))
    eyes = _face_mask(head, "eyes", faces)[face_ids]
    rgb[eyes] = SCLERA
    for eye, iris_region in ((eye_l, "left_iris"), (eye_r, "right_iris")):
        # brows: an arch 0.3..0.52 u above the eye centre, thickest in the middle, over +-0.55 u sideways, on the skin
        dx = (points[:, 0] - eye[0]) / (0.55 * u)
        lift = (points[:, 1] - eye[1]) / u - (0.30 + 0.08 * (1 - dx ** 2))
        brow = (np.abs(dx) < 1) & (lift > 0) & (lift < 0.09 + 0.05 * (1 - dx ** 2)) \
            & (points[:, 2] > eye[2]) & ~eyes
        rgb[brow] = BROW
        iris = _face_mask(head, iris_region, faces)[face_ids]
        rgb[iris] = IRIS
        d = points - eye
        cos = d[:, 2] / np.maximum(np.linalg.norm(d, axis=1), 1e-12)
        rgb[iris & (cos > np.cos(np.radians(PUPIL_DEG)))] = PUPIL
    rgb *= 1 + rng.normal(0, 0.02, (len(points), 1))
    return np.clip(rgb, 0, 1)


def make_bald(head, vertices: np.ndarray, n: int, seed: int = 0) -> GaussianSet:
    """n flat, skin-coloured discs on the head surface (vertices (V, 3)), rest pose, world space,
    with a `binding` extra (host face ids)."""
    from avatarkit.rig.frames import degenerate_faces, triangle_frames
    from avatarkit.rotations import matrix_to_quat

    if int(n) != n or n < 1:
        raise InputError(f"n_bald must be a positive integer, got {n}")
    rng = np.random.default_rng([seed, 7])
    v = np.asarray(vertices, np.float64)
    faces = np.asarray(head.faces)
    usable = np.flatnonzero(~degenerate_faces(v, faces))
    ids, points = sample_surface(v, faces[usable], int(n), rng)
    ids = usable[ids].astype(np.int32)
    _, rotations, _ = triangle_frames(v, faces[ids])          # columns e0, n, b: n is the normal
    tri = v[faces]
    total = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    radius = COVERAGE * np.sqrt(total / (np.pi * n)) * rng.uniform(0.85, 1.15, n)
    scales = np.stack([radius, FLATNESS * radius, radius * rng.uniform(0.85, 1.15, n)], axis=1)
    rgb = bald_colors(head, v, ids, points, rng)
    opacity = rng.uniform(0.92, 1.0, n)
    return GaussianSet.from_colors(points, matrix_to_quat(rotations), scales, opacity, rgb,
                                   extras={"binding": ids})


def make_sample_avatar(n_hair: int = 50_000, n_bald: int = 50_000, style: str = "long_straight",
                       seed: int = 0, cage_vertices: int = 500, progress=None):
    """The sample `Avatar`: template head, `n_bald` bald discs, about `n_hair` hair Gaussians of
    `style` (exactly n_hair unless too few strands root on the scalp), cage and rig.
    progress(done, total) follows the MVC weights, the slow step (tens of seconds at 50k)."""
    from avatarkit.avatar import Avatar, _now, _tool_version
    from avatarkit.hair_rig import HairRig
    from avatarkit.head.ref import HeadRef
    from avatarkit.head.model import HeadModel
    from avatarkit.synthetic.head_hair import make_test_avatar

    if int(n_hair) != n_hair or n_hair < 1:
        raise InputError(f"n_hair must be a positive integer, got {n_hair}")
    head = HeadModel.template()
    shape = np.zeros(head.num_shape, np.float32)
    from avatarkit.avatar import _rest_vertices

    rest = _rest_vertices(head, shape)
    bald = make_bald(head, rest, n_bald, seed)
    test = make_test_avatar(style, int(np.ceil(n_hair * HAIR_SURPLUS)), seed, cage_vertices,
                            head_model=head)
    hair = test.hair if len(test.hair) <= n_hair else test.hair.subset(np.arange(int(n_hair)))
    rig = HairRig.build(head, rest, hair, test.cage, progress=progress, sdf=test.sdf)
    provenance = {"tool": "avatarkit", "version": _tool_version(), "created": _now(),
                  "source_image": None,
                  "generator": f"make_sample_avatar(n_hair={n_hair}, n_bald={n_bald}, "
                               f"style={style!r}, seed={seed})"}
    return Avatar(head, bald, hair, test.cage, rig, shape, HeadRef(), f"sample_{style}", "local",
                  provenance)


__all__ = ["make_sample_avatar", "make_bald", "bald_colors", "sample_surface"]
