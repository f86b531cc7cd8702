"""Hairstyle transfer: one avatar's hair on another avatar's head (the paper's teaser).

    from avatarkit.hairstyle import transfer_hair
    result = transfer_hair(Avatar.load("alice"), Avatar.load("bob"))   # Bob with Alice's hair
    result.save("bob_alice_hair")

Steps (`reseat_hair` does 1-4, `transfer_hair` all):
1. relative: the source's hair Gaussians and cage vertices in the frames of the source head's
   scalp triangles (`ScalpHair`, heads of one topology only);
2. re-seat: the same local values in the frames of the target's rest head (its identity shape:
   other size, other shape), so the hair scales and bends with the scalp it sits on;
3. clean-up: hair Gaussians that are the source's skin (near either head's surface and closer in
   colour and size to the skin there than to the hair) are dropped (`cleanup.skin_in_hair`);
4. assembly: the build's assembly step (`recon.assemble.push_out`): hair centres inside the
   target head, or closer to it than margin / 2, move out along the nearest surface feature's
   pseudo-normal to `margin` outside (exact distances; the target's rig SDF only screens out
   hair far from the head);
5. rig: a fresh cage around the seated hair (`build_cage`, or the carried source cage with
   `cage="carry"` when it still holds the hair), its mean value weights and a new simulation
   model (roots on the target's scalp, the target head's SDF) by `HairRig.build`, the builder
   `Avatar.assemble` uses, so the result saves, loads and bakes like any avatar.

The result keeps the target's head model, identity shape, bald Gaussians, SH frame and source
image; its provenance records both avatars (`provenance["transfer"]`).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from avatarkit.errors import InputError
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.hairstyle.cleanup import SkinCleanup, skin_in_hair
from avatarkit.hairstyle import relative as _relative
from avatarkit.hairstyle.relative import ScalpHair, check_same_topology
from avatarkit.recon.assemble import HAIR_MARGIN

#: pushed hair centres land this far (metres) outside the target head, and none stays closer
#: than half of it (the paper's epsilon; the same as `avatarkit build`'s assembly)
MARGIN = HAIR_MARGIN
#: vertices of the fresh cage (the project's default cage size)
CAGE_VERTICES = 500
CAGE_MODES = ("rebuild", "carry")


@dataclass
class TransferReport:
    """What a re-seat did: counts, the carried cage's volume, seconds per step."""

    source_hair: int = 0          # hair Gaussians of the source
    dropped_skin: int = 0         # ... dropped as the source's skin
    skin_candidates: int = 0      # ... near a head surface, hence classified
    pushed: int = 0               # ... moved out to the margin
    hair: int = 0                 # hair Gaussians of the result
    scale: float = 1.0            # target / source head size (cube root of the rest head volumes)
    carried_cage_volume: float = 0.0  # the source cage re-seated on the target (m^3)
    cage: str = ""                # "rebuilt" or "carried" (transfer_hair only)
    timings: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"source_hair": self.source_hair, "dropped_skin": self.dropped_skin,
                "skin_candidates": self.skin_candidates, "pushed_outside": self.pushed,
                "hair": self.hair, "head_scale": round(float(self.scale), 6),
                "carried_cage_volume": float(self.carried_cage_volume),
                "cage": self.cage or None}


@dataclass(eq=False)
class Reseated:
    """The source's hair on the target head: hair (GaussianSet, world, rest pose), the carried
    cage (`Cage`: the source cage re-seated, before the clean-up and push) and the report."""

    hair: GaussianSet
    carried_cage: object
    report: TransferReport


def _check_avatar(avatar, role: str):
    from avatarkit.avatar import Avatar

    if not isinstance(avatar, Avatar):
        raise InputError(f"the {role} must be an Avatar, got {type(avatar).__name__}")


def _label(avatar) -> str:
    return f"{avatar.name!r}" + (f" ({avatar.path})" if avatar.path is not None else "")


def _head_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    from avatarkit.cage.mesh import signed_volume

    return abs(float(signed_volume(np.asarray(vertices, np.float64), faces)))


def reseat_hair(source, target, margin: float | None = None, *, neighbours: int | None = None,
                cleanup: SkinCleanup | bool = True) -> Reseated:
    """The hair of avatar `source` seated on the head of avatar `target` (steps 1-4 of the
    module docstring): no cage or rig is built (fast; what a hair library view needs).

    margin: metres outside the target head where pushed hair lands (none stays closer than
    margin / 2); neighbours: scalp triangles per position (`ScalpHair`); cleanup: True, False
    or a `SkinCleanup` configuration.
    InputError for a source without hair, heads of different topology, a head without a scalp
    region, or hair left with no Gaussian after the clean-up.
    """
    margin = MARGIN if margin is None else margin
    neighbours = _relative.NEIGHBOURS if neighbours is None else neighbours
    from avatarkit.cage.mesh import Cage
    from avatarkit.recon.assemble import push_out

    _check_avatar(source, "hair source")
    _check_avatar(target, "target")
    if not (isinstance(margin, (int, float, np.floating)) and np.isfinite(margin) and 0 <= margin <= 0.05):
        raise InputError(f"the margin must be between 0 and 0.05 metres, got {margin!r}")
    if len(source.hair) == 0:
        raise InputError(f"the hair source avatar {_label(source)} has no hair Gaussians")
    check_same_topology(source.head_model, target.head_model, f"hair source {source.name!r}",
                        f"target {target.name!r}")
    report = TransferReport(source_hair=len(source.hair))
    t = report.timings
    faces = target.head_model.faces
    src_v = source.rest_head_vertices.astype(np.float64)
    dst_v = target.rest_head_vertices.astype(np.float64)
    report.scale = float(np.cbrt(_head_volume(dst_v, faces) / max(_head_volume(src_v, faces), 1e-30)))

    t0 = time.perf_counter()
    relative = ScalpHair.bind(source.hair, source.head_model, src_v, cage=source.cage,
                              neighbours=neighbours)
    t1 = time.perf_counter()
    hair, cage_vertices = relative.to_world(dst_v)
    carried = Cage(cage_vertices, source.cage.faces)
    report.carried_cage_volume = abs(carried.volume())
    t2 = time.perf_counter()
    t.update(relative=t1 - t0, reseat=t2 - t1)

    if cleanup:
        cfg = cleanup if isinstance(cleanup, SkinCleanup) else SkinCleanup()
        is_skin, cand = skin_in_hair(source.hair, hair.means, source.bald, (src_v, faces),
                                     target.bald, (dst_v, faces), cfg)
        report.dropped_skin, report.skin_candidates = int(is_skin.sum()), int(cand.sum())
        if is_skin.all():
            raise InputError(f"every hair Gaussian of {_label(source)} looks like skin: "
                             "nothing is left to transfer (try cleanup=False / --keep-skin)")
        hair = hair.subset(~is_skin)
    t3 = time.perf_counter()
    means = push_out(hair.means, dst_v, faces, float(margin), screen=_rest_sdf(target))
    report.pushed = int((means != hair.means.astype(np.float64)).any(axis=1).sum())
    hair = hair.replace(means=means)
    report.hair = len(hair)
    t.update(cleanup=t3 - t2, push=time.perf_counter() - t3)
    return Reseated(hair, carried, report)


def _source_entry(avatar) -> dict:
    out = {"name": avatar.name, "path": None if avatar.path is None else str(avatar.path)}
    for key in ("created", "generator", "source_image"):
        if avatar.provenance.get(key):
            out[key] = avatar.provenance[key]
    return out


def _rest_sdf(avatar):
    """The avatar's rest-head SDF from its rig if it fits the rest head (a loaded avatar's
    always does: its rig is checked against the head), else None (HairRig.build makes one, as
    for a hairless avatar, which has no rig)."""
    if avatar.rig is None:
        return None
    sdf = getattr(avatar.rig.model, "sdf", None)
    if sdf is None:
        return None
    v = avatar.rest_head_vertices
    d, _ = sdf.query(v[::max(1, len(v) // 512)])
    return sdf if float(np.abs(d).max()) <= 2.0 * sdf.spacing else None


def transfer_hair(source, target, margin: float | None = None, *, neighbours: int | None = None,
                  cleanup: SkinCleanup | bool = True, cage: str = "rebuild",
                  cage_vertices: int | None = None, name: str | None = None,
                  progress: Callable[[int, int], None] | None = None):
    """`target`'s head and identity with `source`'s hair -> a new `Avatar` (module docstring).

    margin, neighbours, cleanup: as `reseat_hair`. cage: "rebuild" (a fresh cage of at most
    `cage_vertices` vertices around the seated hair) or "carry" (the source's cage re-seated
    on the target, kept when it is still closed and holds every hair centre and axis end;
    else rebuilt). name: the result's name (default "<target>_<source>_hair").
    progress(done, total) follows the cage weights, the slow step.
    The report is in `result.provenance["transfer"]`.
    """
    margin = MARGIN if margin is None else margin
    neighbours = _relative.NEIGHBOURS if neighbours is None else neighbours
    cage_vertices = CAGE_VERTICES if cage_vertices is None else cage_vertices
    import datetime

    from avatarkit import __version__
    from avatarkit.avatar import Avatar
    from avatarkit.hair_rig import HairRig
    from avatarkit.cage.build import build_cage
    from avatarkit.cage.mesh import check_cage
    from avatarkit.cage.points import cage_points

    if cage not in CAGE_MODES:
        raise InputError(f"cage must be one of {', '.join(CAGE_MODES)}, got {cage!r}")
    if isinstance(cage_vertices, bool) or int(cage_vertices) != cage_vertices or cage_vertices < 20:
        raise InputError(f"cage_vertices must be an integer >= 20, got {cage_vertices!r}")
    seated = reseat_hair(source, target, margin, neighbours=neighbours, cleanup=cleanup)
    report = seated.report
    t0 = time.perf_counter()
    if cage == "carry" and check_cage(seated.carried_cage, cage_points(seated.hair)).ok:
        new_cage, report.cage = seated.carried_cage, "carried"
    else:
        new_cage, report.cage = build_cage(seated.hair, target_vertices=int(cage_vertices)), "rebuilt"
    rest = target.rest_head_vertices
    # Avatar.assemble's rig, but with the target's head SDF: it depends on the rest head only,
    # and building it again is most of the rig's time at small hair counts
    rig = HairRig.build(target.head_model, rest, seated.hair, new_cage, source.rig.method,
                        progress=progress, sdf=_rest_sdf(target))
    report.timings["rig"] = time.perf_counter() - t0
    created = datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0)
    prov = {
        "tool": "avatarkit", "version": __version__,
        "created": created.isoformat().replace("+00:00", "Z"),
        "source_image": target.provenance.get("source_image"),
        "generator": f"transfer_hair(hair={source.name!r}, onto={target.name!r}, margin={float(margin):g})",
        "transfer": {"hair_from": _source_entry(source), "head_from": _source_entry(target),
                     "margin_m": float(margin), "neighbours": int(neighbours), **report.to_json()},
    }
    return Avatar(target.head_model, target.bald, seated.hair, new_cage, rig, target.shape,
                  target.head_ref, name or f"{target.name}_{source.name}_hair", target.sh_frame, prov)


__all__ = ["CAGE_MODES", "CAGE_VERTICES", "MARGIN", "Reseated", "TransferReport", "reseat_hair",
           "transfer_hair"]
