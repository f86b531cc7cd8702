"""What the face front end sees, drawn over the photo (`avatarkit face`).

`look_at_faces` runs detection, the face mesh and iris on every face, reads the chosen one again
with test-time augmentation (`face_landmarks(augment=True)`) and fits the head model's
landmarks (`face.fit.fit_landmarks`: pose and shape from the landmarks alone; the build adds
its silhouette terms) to the chosen one; `draw_overlay` draws it all:
boxes (yellow; the chosen face thicker) with the detector's six keypoints (magenta), the 468
mesh points (green), the face outline and lips (white), the irises (cyan circles) and the
fitted head's projected landmarks (red crosses).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avatarkit.errors import InputError
from avatarkit.face.correspondence import FACE_OVAL, LIPS_INNER, LIPS_OUTER

#: `look_at_faces` fits the chosen face's mesh read with test-time augmentation
#: (`face.landmarks.face_landmarks(augment=True)`; session 11)
AUGMENT = True


@dataclass(eq=False)
class FaceLook:
    """faces: list[Face] left to right; meshes: list[FaceMesh] (one per face); index: the chosen
    face; fit: its `LandmarkFit` (None when not fitted); fitted_px: (K, 2) the fitted model's
    projected landmarks; summary: JSON-able figures."""

    faces: list
    meshes: list
    index: int
    fit: object
    fitted_px: np.ndarray | None
    summary: dict


def look_at_faces(image: np.ndarray, face_index: int | None = None, fit: bool = True, model=None,
                  embedding=None, path=None) -> FaceLook:
    """Detect, mesh and (optionally) fit. face_index: which face to fit (default: the largest).
    Raises InputError when there is no face or face_index is out of range; ModelsMissing."""
    from avatarkit.face.detect import detect_faces
    from avatarkit.face.landmarks import face_landmarks

    faces = detect_faces(image)
    # mirror-averaged: the landmark fit reads the pose closer with it (`landmarks.MIRROR_AVERAGE`)
    meshes = [face_landmarks(image, f, mirror=True) for f in faces]
    keep = [i for i, m in enumerate(meshes) if m.presence >= 0.5]
    faces, meshes = [faces[i] for i in keep], [meshes[i] for i in keep]
    if not faces:
        raise InputError("no face found (MediaPipe BlazeFace detectors and face mesh)", path)
    if face_index is None:
        index = int(np.argmax([f.width for f in faces]))
    elif not 0 <= face_index < len(faces):
        raise InputError(f"face index {face_index} is out of range: found {len(faces)} face(s)", path)
    else:
        index = int(face_index)
    summary = {"faces": [{"box_xywh": list(f.xywh()), "score": round(f.score, 3), "detector": f.detector,
                          "presence": round(m.presence, 3)} for f, m in zip(faces, meshes)],
               "chosen": index}
    result, px = None, None
    if fit:
        from scipy.spatial.transform import Rotation

        from avatarkit.face.correspondence import embedding_for
        from avatarkit.face.fit import LandmarkModel, LandmarkTargets, fit_landmarks
        from avatarkit.head.model import HeadModel
        from avatarkit.recon.fit import portrait_focal, view_camera

        model = HeadModel.template() if model is None else model
        # the embedding made from the mirror-averaged mesh these are (`correspondence.MIRROR_TEMPLATE_FILE`)
        emb = embedding if embedding is not None else embedding_for(model, mirror=True, carry_jaw=False)
        if emb is not None:
            h, w = image.shape[:2]
            focal = portrait_focal(w, h)
            # the fitted face read with test-time augmentation (`face_landmarks(augment=True)`):
            # 120 shaded template renders 2.19 -> 1.86 deg median rotation error (docs/face.md)
            meshes[index] = face_landmarks(image, faces[index], mirror=True, augment=AUGMENT)
            targets = LandmarkTargets.from_mesh(meshes[index], emb, (w, h))
            result = fit_landmarks(model, emb, targets, focal)
            pts = LandmarkModel(model, emb).points_numpy(result.shape)
            px = view_camera(result.rotation, result.translation, w, h, focal).project(pts)[0]
            yaw, pitch, roll = Rotation.from_rotvec(result.rotation).as_euler("YXZ", degrees=True)
            summary["fit"] = {"yaw_deg": round(float(yaw), 2), "pitch_deg": round(float(pitch), 2),
                              "roll_deg": round(float(roll), 2), "landmarks": len(emb),
                              "median_error_px": round(result.median_error, 3)}
    return FaceLook(faces, meshes, index, result, px, summary)


def draw_overlay(image: np.ndarray, look: FaceLook) -> np.ndarray:
    """(H, W, 3) uint8: the photo with `look` drawn over it (module docstring)."""
    import cv2

    out = np.ascontiguousarray(image[..., :3]).copy()
    h, w = out.shape[:2]
    t = max(1, round(max(h, w) / 600))
    shift = 4
    s = float(1 << shift)

    def pt(p):
        # our pixel centres are at i + 0.5; OpenCV draws at integer indices
        return (int(round((float(p[0]) - 0.5) * s)), int(round((float(p[1]) - 0.5) * s)))

    for i, (face, mesh) in enumerate(zip(look.faces, look.meshes)):
        x0, y0, x1, y1 = face.box
        cv2.rectangle(out, pt((x0, y0)), pt((x1, y1)), (255, 220, 0), t * (2 if i == look.index else 1),
                      cv2.LINE_AA, shift)
        for k in face.keypoints:
            cv2.circle(out, pt(k), int(2 * t * s), (255, 0, 255), -1, cv2.LINE_AA, shift)
        for p in mesh.points:
            cv2.circle(out, pt(p), int(max(1, t) * s), (0, 230, 0), -1, cv2.LINE_AA, shift)
        for loop in (FACE_OVAL, LIPS_OUTER, LIPS_INNER):
            poly = np.array([pt(mesh.points[j]) for j in loop], np.int32)
            cv2.polylines(out, [poly], True, (255, 255, 255), t, cv2.LINE_AA, shift)
        for c, r in zip(mesh.iris_centers, mesh.iris_radii):
            cv2.circle(out, pt(c), int(max(r, 1.0) * s), (0, 255, 255), t, cv2.LINE_AA, shift)
    if look.fitted_px is not None:
        for p in look.fitted_px:
            if np.isfinite(p).all():
                cv2.drawMarker(out, (int(p[0]), int(p[1])), (255, 40, 40), cv2.MARKER_CROSS, 4 * t, t)
    return out
