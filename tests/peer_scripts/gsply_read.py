"""Run by tests in a peer venv with gsply: read PLY files with gsply and save what it returns.

usage: python gsply_read.py OUT.npz FILE.ply ...  -> OUT.npz with `<i>_<field>` arrays for the
i-th file (means, quats, scales, opacities, sh0, shN as gsply returns them: PLY values), or
`<i>_error` holding the message when gsply raised.
"""
import sys

import numpy as np

import gsply


def main(out, *paths):
    arrays = {}
    for i, path in enumerate(paths):
        try:
            data = gsply.plyread(path)
        except Exception as e:  # what the peer says about the file
            arrays[f"{i}_error"] = np.array(f"{type(e).__name__}: {e}")
            continue
        for field in ("means", "quats", "scales", "opacities", "sh0", "shN"):
            arrays[f"{i}_{field}"] = np.asarray(getattr(data, field))
    np.savez(out, **arrays)


if __name__ == "__main__":
    main(*sys.argv[1:])
