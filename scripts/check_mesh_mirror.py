"""Re-derive the face mesh's left/right pairing from the mesh model's own answers and compare it
with the one `avatarkit.face.landmarks.mirror_pairs` builds from the canonical model's midline.

The template head is rendered facing the camera (`recon.fit.synthetic_head_view`, flat colours)
and averaged with its mirror image, so the picture is exactly left/right symmetric about the
image's centre column; the plain face mesh (`mirror=False`: the averaged one is symmetric
under whatever pairing it is averaged with) runs on it, and each point is paired with the point
nearest its mirror image (x -> W - x), one-to-one (Hungarian assignment on the pixel
distances). Prints whether that pairing is an involution, how many points it fixes, where it
differs from `mirror_pairs`, and how far the points sit from their partners' mirror images.
Then the same on the sample portrait and its mirror image (the mesh of the mirror image mirrored
back), which uses no symmetric picture at all: expect a few disagreements there among the
tightly packed eye and lip points, where the model's left/right inconsistency (what
`face_landmarks(mirror=True)` averages away) is as large as the spacing.

    .venv/bin/python scripts/check_mesh_mirror.py
"""
from __future__ import annotations

import os

os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")
os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")

import numpy as np  # noqa: E402


def nearest_pairing(points: np.ndarray, mirrored: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """pi (468,) with mirrored[i] nearest points[pi[i]] (one-to-one), and those distances."""
    from scipy.optimize import linear_sum_assignment

    d = np.linalg.norm(points[None, :, :2] - mirrored[:, None, :2], axis=2)
    rows, cols = linear_sum_assignment(d)
    return cols, d[rows, cols]


def report(name: str, pi: np.ndarray, dist: np.ndarray, eye: float) -> None:
    from avatarkit.face.landmarks import mirror_pairs

    ref = mirror_pairs()
    n = len(pi)
    differ = np.flatnonzero(pi != ref)
    print(f"{name}: involution {bool(np.array_equal(pi[pi], np.arange(n)))}, fixed points "
          f"{int((pi == np.arange(n)).sum())}, differs from mirror_pairs at {len(differ)} of {n}"
          + (f" (e.g. {differ[:8].tolist()})" if len(differ) else "")
          + f"; distance to the partner's mirror image median {np.median(dist) / eye:.3f}, "
          f"max {dist.max() / eye:.3f} eye distances")


def main() -> None:
    from avatarkit.face import detect_faces, face_landmarks
    from avatarkit.recon.fit import synthetic_head_view
    from avatarkit.recon.image_io import read_image

    image = synthetic_head_view(size=512, n_gaussians=40000, seed=3).image.astype(np.float32)
    image = np.round((image + image[:, ::-1]) / 2).astype(np.uint8)
    W = image.shape[1]
    p = face_landmarks(image, max(detect_faces(image), key=lambda f: f.score), mirror=False).points
    p = p.astype(np.float64)
    eye = float(np.linalg.norm(p[33, :2] - p[263, :2]))
    m = p.copy()
    m[:, 0] = W - m[:, 0]
    report("symmetric template render", *nearest_pairing(p, m), eye)

    root = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
    image = read_image(os.path.join(root, "samples", "portrait.jpg"))
    W = image.shape[1]
    p = face_landmarks(image, max(detect_faces(image), key=lambda f: f.score), mirror=False).points
    p = p.astype(np.float64)
    flipped = np.ascontiguousarray(image[:, ::-1])
    q = face_landmarks(flipped, max(detect_faces(flipped), key=lambda f: f.score), mirror=False).points
    q = q.astype(np.float64)
    q[:, 0] = W - q[:, 0]
    eye = float(np.linalg.norm(p[33, :2] - p[263, :2]))
    report("sample portrait vs its mirror image", *nearest_pairing(p, q), eye)


if __name__ == "__main__":
    main()
