"""Test-only peers that cannot live in the project's environment: a second Python virtual
environment (an older usd-core; a package that pulls numba) or an npm package (PlayCanvas
`splat-transform`, `@spz-loader/core`).

Each is installed once into `.peers/<name>/` at the repository root (gitignored) and reused by
later runs; its exact requirements are the cache key. A test that needs one skips, saying why,
when it cannot be made (no node/npm, no registry).
"""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

PEERS = Path(__file__).resolve().parents[1] / ".peers"
SCRIPTS = Path(__file__).resolve().parent / "peer_scripts"
#: seconds an install may take (a cold pip/npm cache on a shared machine)
INSTALL_TIMEOUT = 1200


def _last_line(text: str) -> str:
    lines = [s for s in text.strip().splitlines() if s.strip()]
    return lines[-1] if lines else "no output"


def _ready(folder: Path, key: str) -> bool:
    stamp = folder / ".installed"
    return stamp.is_file() and stamp.read_text() == key


def python_peer(name: str, requirements: list[str]) -> Path:
    """The python executable of a venv `.peers/<name>` holding exactly `requirements`."""
    folder = PEERS / name
    python = folder / "bin" / "python"
    key = "\n".join(requirements) + "\n"
    if _ready(folder, key) and python.exists():
        return python
    shutil.rmtree(folder, ignore_errors=True)
    folder.parent.mkdir(parents=True, exist_ok=True)
    made = subprocess.run([sys.executable, "-m", "venv", str(folder)], capture_output=True, text=True)
    if made.returncode:
        pytest.skip(f"cannot make a peer venv: {_last_line(made.stderr)}")
    try:
        pip = subprocess.run([str(python), "-m", "pip", "install", "-q", *requirements],
                             capture_output=True, text=True, timeout=INSTALL_TIMEOUT)
    except subprocess.TimeoutExpired:
        pytest.skip(f"installing {' '.join(requirements)} took over {INSTALL_TIMEOUT} s")
    if pip.returncode:
        pytest.skip(f"cannot install {' '.join(requirements)} into a peer venv: {_last_line(pip.stderr)}")
    (folder / ".installed").write_text(key)
    return python


def npm_peer(name: str, packages: list[str]) -> Path:
    """The folder `.peers/<name>` whose node_modules holds exactly `packages` (npm specs)."""
    if shutil.which("node") is None or shutil.which("npm") is None:
        pytest.skip("node and npm are not installed (Debian: apt-get install -y nodejs npm)")
    folder = PEERS / name
    key = "\n".join(packages) + "\n"
    if _ready(folder, key):
        return folder
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    (folder / "package.json").write_text(json.dumps({"name": f"avatarkit-peer-{name}", "private": True}))
    try:
        npm = subprocess.run(["npm", "install", "--no-audit", "--no-fund", "--ignore-scripts", *packages],
                             cwd=folder, capture_output=True, text=True, timeout=INSTALL_TIMEOUT)
    except subprocess.TimeoutExpired:
        pytest.skip(f"installing {' '.join(packages)} took over {INSTALL_TIMEOUT} s")
    if npm.returncode:
        pytest.skip(f"cannot npm install {' '.join(packages)}: {_last_line(npm.stderr)}")
    (folder / ".installed").write_text(key)
    return folder


def run_peer(args: list, timeout: float = 300, **kw) -> subprocess.CompletedProcess:
    """Run a peer's command; its output is captured as text."""
    return subprocess.run([str(a) for a in args], capture_output=True, text=True, timeout=timeout, **kw)
