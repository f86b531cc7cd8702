"""Re-make the built-in template head's face-mesh correspondence
(avatarkit/face/data/template_mediapipe_embedding.npz): render the template from a few views,
run MediaPipe's face mesh on each, cast every landmark onto the template's triangles
(`avatarkit.face.correspondence.make_template_embedding`). With --mirror, the embedding for the
mirror-averaged face mesh (avatarkit/face/data/template_mediapipe_embedding_mirror.npz: that
mesh, at the 35 views of `MIRROR_TEMPLATE_VIEWS`).

    .venv/bin/python scripts/make_face_correspondence.py [--mirror] [-o FILE]

Run it again whenever the template head's mesh or its bald-Gaussian colouring changes.
"""
from __future__ import annotations

import argparse
import json
import os
import time

os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")
os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")

from avatarkit.face.correspondence import (MIRROR_TEMPLATE_FILE, MIRROR_TEMPLATE_VIEWS, TEMPLATE_FILE,  # noqa: E402
                                           make_template_embedding)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mirror", action="store_true", help="for the mirror-averaged face mesh")
    ap.add_argument("-o", "--output", default=None)
    args = ap.parse_args()
    t0 = time.perf_counter()
    if args.mirror:
        embedding, report = make_template_embedding(MIRROR_TEMPLATE_VIEWS, mirror=True)
    else:
        embedding, report = make_template_embedding()
    args.output = args.output or str(MIRROR_TEMPLATE_FILE if args.mirror else TEMPLATE_FILE)
    embedding.save(args.output)
    print(json.dumps(report, indent=1))
    print(f"wrote {args.output}: {len(embedding)} landmarks, {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
