"""Every `avatarkit ...` line in a fenced block of README.md or docs/*.md must parse with the CLI:
the command path resolves, options and arguments are known and well-formed (click's own parser and
types, as `--help`-level validation; nothing runs). Usage brackets (`[--split]`) count as given.
Alternatives `a|b` are each checked. A renamed option or command fails here instead of leaving the
docs wrong."""
import re
import shlex
from pathlib import Path

import click
import pytest

from avatarkit.cli.main import cli

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
COMMAND = re.compile(r"(\$ )?(\S*/)?avatarkit(\s|$)")


def doc_commands(text: str) -> list[tuple[int, str]]:
    """(line number, command line) of each avatarkit line inside ``` fences, `\\` continuations
    joined, prompt and path before `avatarkit` dropped."""
    out, fence, buf, start = [], False, "", 0
    for no, line in enumerate(text.splitlines(), 1):
        if line.startswith("```"):
            fence = not fence
            continue
        s = line.strip()
        if not fence:
            continue
        if buf:
            buf += " " + s
        elif COMMAND.match(s):
            buf, start = s, no
        else:
            continue
        if buf.endswith("\\"):
            buf = buf[:-1]
            continue
        out.append((start, buf))
        buf = ""
    return out


def split_args(line: str) -> list[str]:
    """The arguments after `avatarkit`: shell comments and pipes cut, usage brackets opened."""
    words = shlex.split(line.split(" | ")[0], comments=True)
    while not words[0].endswith("avatarkit"):
        words.pop(0)
    return [w.strip("[]") for w in words[1:] if w.strip("[]")]


def check(args: list[str]) -> click.Command:
    """Resolve the command path of `args` and parse the rest with that command's parser."""
    cmd, ctx, name = cli, None, "avatarkit"
    while isinstance(cmd, click.Group):
        ctx = click.Context(cmd, info_name=name, parent=ctx)
        if not args:
            raise click.UsageError(f"{name}: no command given", ctx)
        name, cmd, args = cmd.resolve_command(ctx, args)
    cmd.make_context(name, list(args), parent=ctx)
    return cmd


@pytest.fixture
def no_path_checks(monkeypatch):
    """The examples name files that do not exist here: keep every other check of click.Path."""
    def visit(cmd):
        for p in cmd.params:
            if isinstance(p.type, click.Path):
                monkeypatch.setattr(p.type, "exists", False)
        if isinstance(cmd, click.Group):
            for sub in cmd.list_commands(None):
                visit(cmd.get_command(None, sub))
    visit(cli)


EXAMPLES = [(page, no, line) for page in PAGES for no, line in doc_commands(page.read_text(encoding="utf-8"))]


def test_the_docs_have_examples():
    assert len(EXAMPLES) >= 40
    assert {p.name for p, _, _ in EXAMPLES} >= {"README.md", "building.md", "batch.md", "rendering.md"}


def variants(args: list[str]) -> list[list[str]]:
    """Usage alternatives `auto|mediapipe|cascade` (a word with `|` and no spaces): one argument
    list per alternative of each such word (the others at their first)."""
    first = [w.split("|")[0] for w in args]
    out = [first]
    for i, w in enumerate(args):
        for alt in w.split("|")[1:]:
            out.append(first[:i] + [alt] + first[i + 1:])
    return out


@pytest.mark.parametrize("page, no, line", EXAMPLES, ids=[f"{p.name}:{n}" for p, n, _ in EXAMPLES])
def test_doc_command_parses(no_path_checks, page, no, line):
    for args in variants(split_args(line)):
        try:
            check(args)
        except click.ClickException as e:
            pytest.fail(f"{page.name}:{no}: `{' '.join(args)}`: {e.format_message()}")


@pytest.mark.parametrize("line, words", [
    ("avatarkit bake a.avatar c.npz -o x.usdc --no-such-option", "no-such-option"),
    ("avatarkit motion jump -o x.npz", "jump"),
    ("avatarkit render head.ply -o x.png --turntable many", "many"),
    ("avatarkit convert scene.ply", "-o"),
    ("avatarkit head", "no command"),
])
def test_a_wrong_example_fails(no_path_checks, line, words):
    with pytest.raises(click.ClickException) as e:
        check(split_args(line))
    assert words in e.value.format_message()


def test_extraction_joins_continuations_and_opens_brackets():
    text = "x\n```bash\n$ .venv/bin/avatarkit bake a b \\\n   -o c.usdc  # note\necho avatarkit\n```\n" \
           "avatarkit outside a fence\n```\navatarkit head info [--head-model FILE] [--json] | jq .\n```\n"
    got = doc_commands(text)
    assert [n for n, _ in got] == [3, 9]
    assert split_args(got[0][1]) == ["bake", "a", "b", "-o", "c.usdc"]
    assert split_args(got[1][1]) == ["head", "info", "--head-model", "FILE", "--json"]
    assert variants(["x", "--m", "a|b|c"]) == [["x", "--m", "a"], ["x", "--m", "b"], ["x", "--m", "c"]]
