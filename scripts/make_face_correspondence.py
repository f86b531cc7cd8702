"""Re-make the built-in template head's face-mesh correspondence
(avatarkit/face/data/template_mediapipe_embedding.npz): render the template from a few views,
run MediaPipe's face mesh on each, cast every landmark onto the template's triangles
(`avatarkit.face.correspondence.make_template_embedding`).

    .venv/bin/python scripts/make_face_correspondence.py [-o FILE]

Run it again whenever the template head's mesh or its bald-Gaussian colouring changes.
"""
from __future__ import annotations

import argparse
import json
import os
import time

os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")
os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")

from avatarkit.face.correspondence import TEMPLATE_FILE, make_template_embedding  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--output", default=str(TEMPLATE_FILE))
    args = ap.parse_args()
    t0 = time.perf_counter()
    embedding, report = make_template_embedding()
    embedding.save(args.output)
    print(json.dumps(report, indent=1))
    print(f"wrote {args.output}: {len(embedding)} landmarks, {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
