"""Re-make the built-in template head's view-dependent landmark correction
(avatarkit/face/data/template_view_correction.npz, `avatarkit.face.view_correction`).

Renders the template head Lambert-shaded (`synthetic.shading`) at random identity shapes, head
rotations (yaw +-45, pitch +-22, roll +-10 deg), positions and jaw openings, from seeds DISJOINT
from the benchmarks' (benchmarks/face.py draws seeds 0-2 and the Gaussian samples 0-11,
benchmarks/track.py a fixed clip on sample 0; this script draws from seed 1000 on):
  - --cases renders as the tracker's videos are made (`HeadVideo(mouth=True)`: a dark mouth
    interior, half of them with the jaw open 0-0.3 rad), a new sample of the skin's Gaussians
    (seeds 1000, 1001, ...) every 40 cases, lit from the upper left or (odd samples) the upper
    right;
  - --stills renders as the portrait fit's tests are (`recon.fit.synthetic_head_view`, jaw
    closed, Gaussian samples 501000 + i), the two lights alternating;
runs the face mesh on each render, and fits, per landmark, a smooth function of the view (the
camera's direction in the head's frame) and the jaw's opening to where the face mesh put the
point relative to where the head's point projects (`view_correction.fit_correction`).

    .venv/bin/python scripts/make_view_correction.py [--cases 1200] [--stills 1000] [-o FILE]

The renders' face meshes are cached (--cache, --stills-cache: delete them to render again; the
shipped file took ~5 + ~6 min of rendering on 2 busy cores) so the fit can be re-run alone.
Re-run after changing the template head, its colouring, or the embedding. The face mesh is the
plain one (`face_landmarks(mirror=False)`), as the shipped file was made and as the tracker runs it.
"""
from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")
os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")

import numpy as np  # noqa: E402

SEED = 1000
#: calibration cases rendered with one sample of the skin's Gaussians
TEXTURE_CASES = 40


def emb_model_shapes() -> int:
    from avatarkit.head.model import HeadModel

    return HeadModel.template().num_shape


def lights() -> tuple:
    """The benchmarks' light (`shading.LIGHT`) and its mirror image (x negated)."""
    from avatarkit.synthetic.shading import LIGHT

    light = np.asarray(LIGHT, np.float64)
    return light, light * np.array([-1.0, 1.0, 1.0])


def render_cases(cases: int, seed: int, size: int = 512) -> dict:
    """Face meshes of `cases` random renders and their truth (arrays stacked over cases)."""
    from avatarkit.face import detect_faces, face_landmarks
    from avatarkit.face.correspondence import template_embedding
    from avatarkit.motion.clip import MotionClip
    from avatarkit.synthetic.head_video import HeadVideo, head_video_camera

    rng = np.random.default_rng(seed)
    from scipy.spatial.transform import Rotation

    yaw, pitch, roll = rng.uniform(-45, 45, cases), rng.uniform(-22, 22, cases), rng.uniform(-10, 10, cases)
    rot = Rotation.from_euler("YXZ", np.stack([yaw, pitch, roll], 1), degrees=True).as_rotvec()
    # half the cases with the jaw open (0-0.3 rad), the rest closed
    jaw = np.where(rng.uniform(size=cases) < 0.5, rng.uniform(0.0, 0.3, cases), 0.0)
    trans = np.stack([rng.uniform(-0.03, 0.03, cases), rng.uniform(-0.03, 0.03, cases),
                      rng.uniform(-0.12, 0.1, cases)], 1)
    clip = MotionClip(fps=30.0, rotation=rot, translation=trans, neck=np.zeros((cases, 3)),
                      jaw=np.stack([jaw, np.zeros(cases), np.zeros(cases)], 1), eyes=np.zeros((cases, 6)),
                      expr=np.zeros((cases, 9)))
    camera = head_video_camera(size, distance=0.55)
    # a new sample of the skin's Gaussians every TEXTURE_CASES cases (the face mesh reads each
    # sample with a small bias of its own, which a correction must not learn), lit from the
    # upper left for even samples and mirrored (upper right) for odd ones: the face mesh's answer
    # leans with the shading, and a person may be lit from either side
    videos = {}

    def video_for(i):
        key = i // TEXTURE_CASES
        if key not in videos:
            videos.clear()
            videos[key] = HeadVideo(clip, camera, n_gaussians=30000, seed=seed + key, light=lights()[key % 2],
                                    mouth=True)
        return videos[key]
    emb = template_embedding()
    shapes = rng.normal(size=(cases, emb_model_shapes())) * 0.7
    out = {k: [] for k in ("mesh", "truth_cam", "head_to_cam", "shape", "found")}
    for i in range(cases):
        video = video_for(i)
        video.shape = shapes[i].astype(np.float32)
        frame = video.frame(i)
        v = video.vertices(i)
        faces = detect_faces(frame.rgb)
        mesh = face_landmarks(frame.rgb, max(faces, key=lambda q: q.score), mirror=False) if faces else None
        ok = mesh is not None and mesh.presence >= 0.5
        out["found"].append(ok)
        out["mesh"].append(np.asarray(mesh.points, np.float64) if ok else np.full((468, 3), np.nan))
        w = emb.points(v, video.model.faces).astype(np.float64)                       # (K, 3) world
        out["truth_cam"].append(w @ camera.rotation.T + camera.translation)           # OpenCV camera
        out["head_to_cam"].append(camera.rotation @ Rotation.from_rotvec(rot[i]).as_matrix())
        out["shape"].append(shapes[i])
    res = {k: np.asarray(v) for k, v in out.items()}
    res.update(jaw=jaw, rotation=rot, translation=trans, focal=np.float64(camera.fx), size=np.int64(size))
    return res


def render_stills(cases: int, seed: int, size: int = 512) -> dict:
    """Like `render_cases`, through `recon.fit.synthetic_head_view` (the portrait fit's test
    renders: the camera moves around a head at rest, 40,000 Gaussians on the shaped head, the
    jaw closed)."""
    from scipy.spatial.transform import Rotation

    from avatarkit.face import detect_faces, face_landmarks
    from avatarkit.face.correspondence import template_embedding
    from avatarkit.head.model import HeadModel, HeadParams
    from avatarkit.recon.fit import synthetic_head_view

    rng = np.random.default_rng(seed)
    model = HeadModel.template()
    emb = template_embedding()
    out = {k: [] for k in ("mesh", "truth_cam", "head_to_cam", "shape", "found", "rotation")}
    focal = None
    for i in range(cases):
        yaw, pitch, roll = rng.uniform(-45, 45), rng.uniform(-22, 22), rng.uniform(-10, 10)
        shape = rng.normal(size=model.num_shape) * 0.7
        dist, off = rng.uniform(0.45, 0.67), rng.uniform(-0.03, 0.03, 2)
        rot = Rotation.from_euler("YXZ", [yaw, pitch, roll], degrees=True).as_rotvec()
        s = synthetic_head_view(rotation=rot, size=size, distance=dist, shape=shape, offset=off,
                                n_gaussians=40000, seed=seed + i, light=lights()[i % 2])
        cam = s.truth.camera
        focal = cam.fx
        faces = detect_faces(s.image)
        mesh = face_landmarks(s.image, max(faces, key=lambda q: q.score), mirror=False) if faces else None
        ok = mesh is not None and mesh.presence >= 0.5
        rest = model.forward(HeadParams(shape=shape.astype(np.float32), expr=np.zeros((1, model.num_expr))))[0][0]
        out["found"].append(ok)
        out["mesh"].append(np.asarray(mesh.points, np.float64) if ok else np.full((468, 3), np.nan))
        out["truth_cam"].append(cam.to_camera(emb.points(rest, model.faces)))
        out["head_to_cam"].append(cam.rotation.astype(np.float64))   # the world is the head's rest frame
        out["shape"].append(shape)
        out["rotation"].append(rot)
    res = {k: np.asarray(v) for k, v in out.items()}
    res.update(jaw=np.zeros(cases), translation=np.zeros((cases, 3)), focal=np.float64(focal), size=np.int64(size))
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=1200)
    ap.add_argument("--seed", type=int, default=SEED)
    ap.add_argument("--cache", default="/tmp/view_correction_renders.npz")
    ap.add_argument("--stills", type=int, default=1000,
                    help="also this many renders of the portrait fit's kind (`synthetic_head_view`)")
    ap.add_argument("--stills-cache", default="/tmp/view_correction_stills.npz")
    ap.add_argument("--ridge", type=float, default=None)
    ap.add_argument("-o", "--output", default=None, help="default: the built-in template's file")
    args = ap.parse_args()
    if not args.seed >= 1000:
        raise SystemExit("calibration seeds start at 1000 (the benchmarks use 0-2)")
    t0 = time.perf_counter()
    if os.path.exists(args.cache):
        data = dict(np.load(args.cache))
        print(f"read {args.cache}: {len(data['found'])} cases")
    else:
        data = render_cases(args.cases, args.seed)
        np.savez_compressed(args.cache, **data)
        print(f"rendered {len(data['found'])} cases ({int(data['found'].sum())} with a face), "
              f"{time.perf_counter() - t0:.1f} s; cached in {args.cache}")
    from avatarkit.face.correspondence import template_embedding
    from avatarkit.face.view_correction import TEMPLATE_FILE, fit_correction, samples_from_renders

    if args.stills:
        if os.path.exists(args.stills_cache):
            stills = dict(np.load(args.stills_cache))
        else:
            stills = render_stills(args.stills, args.seed + 500_000)
            np.savez_compressed(args.stills_cache, **stills)
        print(f"{len(stills['found'])} still renders ({int(stills['found'].sum())} with a face)")
        data = {k: np.concatenate([data[k], stills[k]]) if np.ndim(data[k]) else data[k] for k in data}
    emb = template_embedding()
    samples = samples_from_renders(data, emb)
    kw = {} if args.ridge is None else {"ridge": args.ridge}
    corr, report = fit_correction(samples, emb.mesh_index, **kw)
    out = args.output or TEMPLATE_FILE
    corr.save(out)
    print(report)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
