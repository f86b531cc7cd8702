"""Re-make the built-in template head's shipped surface (avatarkit/head/data/template_surface.npz):
the marching-cubes + remeshing result of `avatarkit.head.template.generate_head_surface`, keyed by
a hash of the code that generates it, so a process loads it instead of spending ~2.5 s on it.

    .venv/bin/python scripts/make_template_surface.py [-o FILE]

Run it again whenever avatarkit/head/template.py, remesh.py or sdf.py changes (until then the
template is generated at run time, and tests/test_head_template.py says the file is stale).
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from avatarkit.head.template import SURFACE_FILE, generate_head_surface, surface_sources_sha256


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--output", default=str(SURFACE_FILE))
    args = ap.parse_args()
    t0 = time.perf_counter()
    vertices, faces = generate_head_surface()
    np.savez_compressed(args.output, vertices=vertices, faces=faces,
                        sources_sha256=np.array(surface_sources_sha256()))
    print(f"wrote {args.output}: {len(vertices)} vertices, {len(faces)} faces, "
          f"{time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
