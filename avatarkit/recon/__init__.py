"""Image -> avatar reconstruction, one stage per module (paper section 3.2).

2D stages: `image_io` (read any common portrait image), `portrait` (face detection, coarse
landmarks, canonical crop), `segment` (background / skin / hair / body labels), `bald`
(the 2D bald filter: hair removed, scalp filled with skin).
"""
