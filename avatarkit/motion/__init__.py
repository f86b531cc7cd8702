"""Motion clips: FLAME parameter sequences, their files and procedural generators."""
from avatarkit.motion.clip import DEFAULT_FPS, ExprDimsWarning, MotionClip
from avatarkit.motion.io import load_clip, save_clip
from avatarkit.motion.procedural import KINDS, make_clip
from avatarkit.motion.summary import format_summary, summarize

__all__ = ["DEFAULT_FPS", "ExprDimsWarning", "KINDS", "MotionClip", "format_summary", "load_clip",
           "make_clip", "save_clip", "summarize"]
