"""The resource bounds every command checks before it allocates or loops (docs/safety.md).

They are generous for real work and stop what would otherwise run for ever or exhaust memory: a
header, a flag or a file claiming sizes far beyond them is refused with a message naming the
bound, before anything is allocated.
"""
from __future__ import annotations

#: frame rates a clip, a bake or a sequence may have (frames per second). Below: a frame per
#: 100 s; above: far past any capture rate, and the simulation's time step would vanish.
MIN_FPS = 0.01
MAX_FPS = 10_000.0

#: seconds of hair settling before a bake's first frame (`bake --preroll`)
MAX_PREROLL_SECONDS = 60.0

#: pixels of one rendered image (width x height): 64 megapixels (8192 x 8192)
MAX_RENDER_PIXELS = 8192 * 8192
#: the largest width or height of a render
MAX_RENDER_SIDE = 16384

#: bytes the arrays of one .npz may hold once decompressed, from the sizes the file declares
MAX_NPZ_BYTES = 4 << 30

#: nesting depth of the JSON documents we read (clips, batch files, manifests, sidecars)
MAX_JSON_DEPTH = 64
