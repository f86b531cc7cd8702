"""tools/mutate.py runs its mutants in a scratch copy of the tree, never in the tree itself."""
import importlib.util
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _mutate_module():
    spec = importlib.util.spec_from_file_location("_mutate_tool", ROOT / "tools" / "mutate.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclass looks its module up there
    spec.loader.exec_module(module)
    return module


def _git(cwd, *args):
    subprocess.run(["git", *args], cwd=cwd, check=True, capture_output=True)


def test_the_scratch_copy_holds_what_git_would_track_and_links_shared(tmp_path):
    mutate = _mutate_module()
    repo = tmp_path / "work" / "repo"
    (repo / "pkg").mkdir(parents=True)
    (tmp_path / "work" / "shared" / "data").mkdir(parents=True)
    (repo / ".gitignore").write_text(".venv/\n*.log\n")
    (repo / "pkg" / "mod.py").write_text("X = 1\n")
    _git(repo, "init", "-q")
    _git(repo, "add", ".")
    _git(repo, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "-m", "x")
    (repo / "pkg" / "mod.py").write_text("X = 2\n")            # uncommitted edit: copied as it is
    (repo / "pkg" / "new.py").write_text("Y = 1\n")            # untracked, not ignored: copied
    (repo / ".venv").mkdir()
    (repo / ".venv" / "big").write_text("venv\n")              # ignored: left out
    (repo / "run.log").write_text("log\n")

    copy = mutate.scratch_copy(tmp_path / "scratch", repo)
    assert copy == tmp_path / "scratch" / "repo"
    assert (copy / "pkg" / "mod.py").read_text() == "X = 2\n"
    assert (copy / "pkg" / "new.py").read_text() == "Y = 1\n"
    assert not (copy / ".venv").exists() and not (copy / "run.log").exists()
    assert (copy.parent / "shared").resolve() == (tmp_path / "work" / "shared").resolve()


def test_a_mutation_is_applied_to_the_copy_and_the_tree_keeps_its_bytes(tmp_path):
    mutate = _mutate_module()
    m = next(m for m in mutate.MUTATIONS if m.id == "export.sequence_fps")
    (file, old, new), = m.edits
    before = (ROOT / file).read_bytes()
    copy = tmp_path / "copy"
    (copy / file).parent.mkdir(parents=True)
    (copy / file).write_bytes(before)
    originals, texts = mutate._apply(m, copy)
    assert list(texts) == [copy / file] and new in texts[copy / file]
    assert (ROOT / file).read_bytes() == before
