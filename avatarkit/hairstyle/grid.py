"""A hair library view: one head wearing several hairstyles, side by side in a contact sheet.

Each hairstyle is re-seated on the head (`reseat_hair`: relative to the scalp, skin clean-up,
pushed out to the margin; no cage or rig, so a row costs a second, not a rig build) and rendered
with the head's bald Gaussians at rest. Rows are hairstyles, columns are views; every view uses
one camera for all rows (framing all of them), so sizes compare across the sheet.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from avatarkit.errors import InputError
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.hairstyle import transfer as _transfer

#: named views: (azimuth, elevation) in degrees for `Camera.orbit` (azimuth 0 faces the face)
VIEWS: dict[str, tuple[float, float]] = {
    "front": (0.0, 0.0),
    "three-quarter": (35.0, 5.0),
    "profile": (90.0, 0.0),
    "back": (180.0, 0.0),
    "top": (0.0, 60.0),
}
DEFAULT_VIEWS = ("front", "three-quarter")


def parse_views(text: str | Sequence[str]) -> list[str]:
    """"front,three-quarter" (or a list of names) -> checked view names, in order."""
    names = [n.strip().lower() for n in (text.split(",") if isinstance(text, str) else text)]
    names = [n for n in names if n]
    if not names:
        raise InputError(f"no views given; choose from {', '.join(VIEWS)}")
    bad = [n for n in names if n not in VIEWS]
    if bad:
        raise InputError(f"unknown view {bad[0]!r}; choose from {', '.join(VIEWS)}")
    return names


@dataclass
class HairGrid:
    """image: (H, W, 3) uint8 contact sheet; rows: the hairstyle names (top to bottom);
    views: the column names; reports: one `TransferReport` per re-seated row (None for the
    head's own hair)."""

    image: np.ndarray
    rows: list[str]
    views: list[str]
    reports: list = field(default_factory=list)


def _plain(gs: GaussianSet) -> GaussianSet:
    return gs.replace(extras={})


def _cell_label(row: str, view: str, r: int, c: int) -> str:
    if c == 0:
        return f"{row} ({view})" if r == 0 else row
    return view if r == 0 else ""


def hair_grid(head, hairstyles: Sequence, views: Sequence[str] | None = None, size: int = 384, *,
              include_own: bool = False, margin: float | None = None, cleanup=True,
              background=(1.0, 1.0, 1.0), labels: bool = True, names: Sequence[str] | None = None,
              progress: Callable[[int, int], None] | None = None) -> HairGrid:
    """Avatar `head` wearing the hair of each avatar in `hairstyles` (and, with include_own, its
    own hair first), rendered from each of `views` (names in VIEWS) at size x size pixels.

    labels: write each row's name on its first cell and the view names on the first row;
    names: the rows' names (one per hairstyle; default the avatars' names).
    progress(done, total) counts rendered cells."""
    views = DEFAULT_VIEWS if views is None else views
    margin = _transfer.MARGIN if margin is None else margin
    from avatarkit.export.images import contact_sheet, to_uint8
    from avatarkit.hairstyle.transfer import reseat_hair
    from avatarkit.render import frame_camera, render, scene_bounds

    views = parse_views(views)
    if isinstance(size, bool) or int(size) != size or not 16 <= size <= 4096:
        raise InputError(f"the cell size must be an integer of 16..4096 pixels, got {size!r}")
    hairstyles = list(hairstyles)
    if not hairstyles and not include_own:
        raise InputError("no hairstyles to show: give at least one hair avatar")
    names = [s.name for s in hairstyles] if names is None else [str(n) for n in names]
    if len(names) != len(hairstyles):
        raise InputError(f"got {len(names)} names for {len(hairstyles)} hairstyles")
    bald = _plain(head.bald)
    rows, scenes, reports = [], [], []
    if include_own:
        rows.append("own hair")
        scenes.append(GaussianSet.concat([bald, _plain(head.hair)]))
        reports.append(None)
    for source, row in zip(hairstyles, names):
        seated = reseat_hair(source, head, margin, cleanup=cleanup)
        rows.append(row)
        scenes.append(GaussianSet.concat([bald, _plain(seated.hair)]))
        reports.append(seated.report)
    bounds = np.array([scene_bounds(s) for s in scenes])          # (rows, 2, 3)
    lo, hi = bounds[:, 0].min(axis=0), bounds[:, 1].max(axis=0)
    cameras = [frame_camera((lo, hi), *VIEWS[v], width=int(size), height=int(size)) for v in views]
    images, cells = [], []
    total = len(scenes) * len(cameras)
    for r, scene in enumerate(scenes):
        for c, cam in enumerate(cameras):
            images.append(to_uint8(render(scene, cam, background).rgb))
            cells.append(_cell_label(rows[r], views[c], r, c))
            if progress is not None:
                progress(len(images), total)
    sheet = contact_sheet(images, columns=len(cameras), labels=cells if labels else None,
                          background=tuple(int(round(255 * x)) for x in background))
    return HairGrid(sheet, rows, views, reports)


__all__ = ["DEFAULT_VIEWS", "HairGrid", "VIEWS", "hair_grid", "parse_views"]
