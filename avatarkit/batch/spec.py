"""The batch file: `load_batch(path) -> Batch`, a flat, checked list of `BakeJob`s.

A batch file (JSON, `schemas/batch.schema.json`) holds `defaults` and `jobs`. A job names an
avatar (or a list) and a clip (or a list, or `clips`: a folder of clips); it expands to one
`BakeJob` per avatar x clip. Settings are the job's own over the defaults over the built-in
defaults; the objects `outputs`, `usd`, `ply`, `preview` and `sim` merge key by key.

Input paths are relative to the batch file's folder; output paths are templates relative to
the output folder ({avatar}, {clip}, {name}). Everything that can be wrong with the file itself
(syntax, schema, settings, templates, two jobs writing one output) is a FormatError naming the
file and the job; inputs are not opened here: a missing or corrupt avatar fails its own jobs
when the batch runs, not the batch.
"""
from __future__ import annotations

import json
import os
import re
import string
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any

from avatarkit.bake import BakeConfig
from avatarkit.errors import FormatError, InputError
from avatarkit.fileio import json_loads
from avatarkit.sim.config import SimConfig

BATCH_FORMAT = "avatarkit.batch"
BATCH_VERSION = 1
OUTPUT_KINDS = ("usd", "ply", "preview")
#: built-in defaults, the same as `avatarkit bake`'s (a test checks they agree)
DEFAULT_NAME = "{avatar}/{clip}"
DEFAULT_OUTPUTS = {"usd": "{name}.usdc", "ply": None, "preview": None}
DEFAULT_OPTIONS = {
    "usd": {"half": False, "usd_points": False, "chunk_frames": 50, "head_normals": True},
    "ply": {"split": False},
    "preview": {"size": 384, "orbit": False},
}
PLACEHOLDERS = ("avatar", "clip", "name")
CLIP_EXTENSIONS = (".npz", ".json")
_MERGED = ("outputs", "usd", "ply", "preview", "sim")


@dataclass(frozen=True)
class OutputSpec:
    """One output of a job. kind: "usd" | "ply" | "preview"; path: relative to the output
    folder (POSIX separators); options: the writer's settings, complete (defaults filled in)."""

    kind: str
    path: str
    options: dict = field(default_factory=dict)

    def target(self, outdir: str | os.PathLike) -> Path:
        return Path(outdir) / self.path


@dataclass(frozen=True)
class BakeJob:
    """One avatar baked against one clip into `outputs`. avatar, clip: absolute paths."""

    name: str
    avatar: Path
    clip: Path
    config: BakeConfig
    outputs: tuple[OutputSpec, ...]
    source: str = ""   # where it came from in the batch file, e.g. "jobs[2]"

    def output(self, kind: str) -> OutputSpec | None:
        return next((o for o in self.outputs if o.kind == kind), None)


@dataclass(frozen=True)
class Batch:
    """The jobs of a batch file, in file order (each entry's avatars x clips, avatar-major)."""

    jobs: tuple[BakeJob, ...]
    path: Path | None = None

    def __len__(self) -> int:
        return len(self.jobs)


# --- reading -----------------------------------------------------------------------------------

def load_batch(path: str | os.PathLike) -> Batch:
    """Read, check and expand a batch file (FormatError naming the file and the job at fault)."""
    path = Path(path)
    if path.is_dir():
        raise InputError("is a folder, not a batch file", path)
    if not path.is_file():
        raise InputError("batch file not found", path)
    if path.suffix.lower() in (".yaml", ".yml"):
        raise FormatError("batch files are JSON (.json); YAML is not supported", path)
    try:
        doc = json_loads(path.read_text(encoding="utf-8"), path)
    except UnicodeDecodeError:
        raise FormatError("not a text file (batch files are JSON)", path) from None
    except json.JSONDecodeError as e:
        raise FormatError(f"not valid JSON: {e.msg} at line {e.lineno}, column {e.colno}", path) from None
    except OSError as e:
        raise InputError(f"cannot read: {e.strerror}", path) from None
    return parse_batch(doc, base=path.resolve().parent, path=path)


def parse_batch(doc: Any, base: str | os.PathLike = ".", path: str | os.PathLike | None = None) -> Batch:
    """A batch from its parsed JSON `doc`; relative input paths are taken from `base`."""
    from avatarkit.schemas import validate

    if isinstance(doc, dict) and isinstance(doc.get("jobs"), list):
        for i, entry in enumerate(doc["jobs"]):  # clearer than the schema's oneOf message
            if isinstance(entry, dict) and ("clip" in entry) == ("clips" in entry):
                raise FormatError(f"jobs[{i}] needs exactly one of 'clip' (a clip or a list) or "
                                  f"'clips' (a folder of clips)", path)
    validate(doc, "batch", path)
    base = Path(base)
    defaults = doc.get("defaults", {})
    jobs: list[BakeJob] = []
    for i, entry in enumerate(doc["jobs"]):
        where = f"jobs[{i}]"
        settings = _merge(defaults, entry)
        try:
            config = _bake_config(settings)
        except InputError as e:
            raise FormatError(f"{where}: {e.message}", path) from None
        avatars = _as_list(entry["avatar"])
        if "clips" in entry:
            clips = _clips_in_folder(_resolve(base, entry["clips"]), where, path)
        else:
            clips = [_resolve(base, c) for c in _as_list(entry["clip"])]
        for a in avatars:
            avatar = _resolve(base, a)
            for clip in clips:
                jobs.append(_make_job(settings, avatar, clip, config, where, path))
    _check_unique(jobs, path)
    return Batch(tuple(jobs), Path(path) if path is not None else None)


def _as_list(value) -> list:
    return list(value) if isinstance(value, list) else [value]


def _resolve(base: Path, p: str) -> Path:
    q = Path(os.path.expanduser(p))
    return Path(os.path.normpath(q if q.is_absolute() else base / q))


def _merge(defaults: dict, job: dict) -> dict:
    """Built-in defaults < batch defaults < job; the `_MERGED` objects key by key."""
    out: dict[str, Any] = {"name": DEFAULT_NAME, "outputs": dict(DEFAULT_OUTPUTS),
                           **{k: dict(v) for k, v in DEFAULT_OPTIONS.items()}, "sim": {}}
    for layer in (defaults, job):
        for key, value in layer.items():
            if key in _MERGED:
                out[key] = {**out[key], **value}
            else:
                out[key] = value
    return out


def _frames(value) -> tuple[int, int | None] | None:
    if value is None:
        return None
    if isinstance(value, list):
        return int(value[0]), (None if value[1] is None else int(value[1]))
    return BakeConfig.parse_frames(str(value))


def _bake_config(settings: dict) -> BakeConfig:
    sim = dict(settings["sim"])
    if "gravity" in sim:
        sim["gravity"] = tuple(sim["gravity"])
    return BakeConfig(frames=_frames(settings.get("frames")), fps=settings.get("fps"),
                      sim=SimConfig(**sim), preroll=settings.get("preroll"))


def _clips_in_folder(folder: Path, where: str, path) -> list[Path]:
    """Every clip file (.npz, .json) in `folder`, and every sub-folder that is a per-frame
    sequence (holds .npz files or a flame_param/ folder), in natural name order."""
    if not folder.is_dir():
        raise FormatError(f"{where}: clips folder {folder} not found", path)
    found = []
    for p in folder.iterdir():
        if p.name.startswith("."):
            continue
        if p.is_file() and p.suffix.lower() in CLIP_EXTENSIONS:
            found.append(p)
        elif p.is_dir() and ((p / "flame_param").is_dir() or any(p.glob("*.npz"))):
            found.append(p)
    if not found:
        raise FormatError(f"{where}: clips folder {folder} holds no clips (.npz, .json or folders "
                          "of per-frame .npz files)", path)
    return sorted(found, key=_natural_key)


def _natural_key(p: Path):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", p.name)]


def clip_label(clip: Path) -> str:
    """{clip} of a job: the file name without its extension (a folder: its name)."""
    return clip.stem if clip.suffix.lower() in CLIP_EXTENSIONS else clip.name


def _expand(template: str, values: dict[str, str], what: str) -> str:
    try:
        fields = [f for _, f, _, _ in string.Formatter().parse(template) if f is not None]
    except ValueError as e:
        raise InputError(f"{what}: bad template {template!r} ({e})") from None
    for f in fields:
        if f not in values:
            raise InputError(f"{what}: unknown placeholder {{{f}}} in {template!r}; use "
                             + ", ".join(f"{{{p}}}" for p in PLACEHOLDERS if p in values))
    return template.format_map(values)


def _relative_output(text: str, what: str) -> str:
    """`text` as a normalised POSIX path that stays inside the output folder."""
    p = PurePosixPath(text.replace("\\", "/"))
    if p.is_absolute() or re.match(r"^[A-Za-z]:", text):
        raise InputError(f"{what}: {text!r} must be relative to the output folder")
    parts = [s for s in p.parts if s not in ("", ".")]
    if not parts or ".." in parts:
        raise InputError(f"{what}: {text!r} must name a path inside the output folder")
    return "/".join(parts)


def _make_job(settings: dict, avatar: Path, clip: Path, config: BakeConfig, where: str, path) -> BakeJob:
    values = {"avatar": avatar.name, "clip": clip_label(clip)}
    try:
        name = _expand(settings["name"], values, f"{where}: name")
        values["name"] = _relative_output(name, f"{where}: name")
        outputs = []
        for kind in OUTPUT_KINDS:
            template = settings["outputs"].get(kind)
            if template is None:
                continue
            rel = _relative_output(_expand(template, values, f"{where}: outputs.{kind}"),
                                   f"{where}: outputs.{kind}")
            outputs.append(OutputSpec(kind, rel, dict(settings[kind])))
        if not outputs:
            raise InputError(f"{where}: no outputs (every output is null)")
    except InputError as e:
        raise FormatError(e.message, path) from None
    return BakeJob(values["name"], avatar, clip, config, tuple(outputs), where)


def _check_unique(jobs: list[BakeJob], path) -> None:
    names: dict[str, BakeJob] = {}
    targets: dict[str, tuple[BakeJob, str]] = {}
    for job in jobs:
        other = names.setdefault(job.name, job)
        if other is not job:
            raise FormatError(f"two jobs are named {job.name!r} ({other.source}: {other.avatar.name} x "
                              f"{other.clip.name} and {job.source}: {job.avatar.name} x {job.clip.name}); "
                              "give them distinct names (the 'name' template)", path)
        for o in job.outputs:
            key = o.path.lower()  # case-insensitive file systems would merge them
            other, kind = targets.setdefault(key, (job, o.kind))
            if other is job and kind == o.kind:
                continue
            who = f"{job.name!r} ({kind} and {o.kind})" if other is job else f"{other.name!r} and {job.name!r}"
            raise FormatError(f"{who} both write {o.path}: give them distinct names or output templates",
                              path)


__all__ = ["BATCH_FORMAT", "BATCH_VERSION", "Batch", "BakeJob", "OutputSpec", "OUTPUT_KINDS",
           "clip_label", "load_batch", "parse_batch"]
