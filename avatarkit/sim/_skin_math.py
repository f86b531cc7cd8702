"""Constants shared by the Taichi kernels and their numpy twins (importable without Taichi)."""

#: a point whose head-joint weight is at least this is taken to the rest frame by the head joint
#: alone (the skull, the scalp: most of what hair touches), which skips inverting the blend
RIGID_WEIGHT = 0.999
#: joints of the skinned collision (head joint first)
JMAX = 4
