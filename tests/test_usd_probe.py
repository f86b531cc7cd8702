"""The child-process probe before OpenUSD opens a binary file (`gaussians.usd_probe`): a file that
crashes USD's C++ reader is a one-line FormatError naming it, never a dead process."""
from __future__ import annotations

import subprocess

import pytest

from avatarkit.cli.main import main
from avatarkit.errors import FormatError
from avatarkit.gaussians import usd_probe
from avatarkit.gaussians.usd import save_usd
from avatarkit.gaussians.usd_read import load_usd
from helpers import random_gaussians


@pytest.fixture
def crate(tmp_path):
    path = tmp_path / "s.usdc"
    save_usd(path, random_gaussians(12, sh_degree=1, seed=2, extras=("part",)))
    return path


@pytest.fixture
def fresh_cache(monkeypatch):
    monkeypatch.setattr(usd_probe, "_probed", set())
    monkeypatch.delenv(usd_probe.PROBE_ENV, raising=False)


def _count_children(monkeypatch):
    calls = []
    real = subprocess.run

    def run(*a, **k):
        calls.append(a)
        return real(*a, **k)

    monkeypatch.setattr(usd_probe.subprocess, "run", run)
    return calls


def test_the_fuzz_find_that_crashed_the_reader_is_a_format_error(crate, fresh_cache, capsys):
    """The long run's find (session 13): byte 89 of this seed, 1 -> 63, made `Usd.Stage.Open`
    segfault. Without the probe this test's process would die here."""
    data = bytearray(crate.read_bytes())
    data[89] = 63 if data[89] != 63 else 1
    bad = crate.with_name("bad.usdc")
    bad.write_bytes(bytes(data))
    try:
        load_usd(bad)
    except FormatError as e:
        assert "bad.usdc" in str(e) and "\n" not in str(e)
    assert main(["inspect", str(bad)]) in (0, 2)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) <= 1


def test_a_child_killed_by_a_signal_names_the_file_and_the_signal(crate, fresh_cache, monkeypatch, capsys):
    monkeypatch.setattr(usd_probe, "_CHILD", "import os, signal; os.kill(os.getpid(), signal.SIGSEGV)")
    with pytest.raises(FormatError, match=r"s\.usdc.*crashed on it: SIGSEGV"):
        load_usd(crate)
    assert main(["inspect", str(crate)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "SIGSEGV" in err[0]


def test_an_ordinary_failure_in_the_child_leaves_the_message_to_this_process(tmp_path, fresh_cache, monkeypatch):
    monkeypatch.setattr(usd_probe, "_CHILD", "raise SystemExit(1)")
    junk = tmp_path / "j.usdc"
    junk.write_bytes(b"PXR-USDC" + bytes(40))
    usd_probe.probe_usd_file(junk)  # no error from the probe: the child did not crash
    with pytest.raises(FormatError, match="not a readable USD file"):
        load_usd(junk)


def test_a_child_that_hangs_is_refused(crate, fresh_cache, monkeypatch):
    monkeypatch.setattr(usd_probe, "_CHILD", "import time; time.sleep(30)")
    monkeypatch.setattr(usd_probe, "TIMEOUT_FLOOR_S", 0.5)
    monkeypatch.setattr(usd_probe, "TIMEOUT_S_PER_MB", 0.0)
    with pytest.raises(FormatError, match="did not finish"):
        usd_probe.probe_usd_file(crate)


def test_each_file_is_probed_once_and_again_when_it_changes(crate, fresh_cache, monkeypatch):
    calls = _count_children(monkeypatch)
    n = len(load_usd(crate))
    load_usd(crate)
    assert len(calls) == 1
    save_usd(crate, random_gaussians(5, seed=3))
    assert len(load_usd(crate)) == 5 != n
    assert len(calls) == 2


def test_what_is_probed(tmp_path, crate, fresh_cache, monkeypatch):
    plain = tmp_path / "p.usda"
    save_usd(plain, random_gaussians(4, seed=1))
    assert usd_probe.needs_probe(crate)
    assert not usd_probe.needs_probe(plain)
    layered = tmp_path / "l.usda"
    layered.write_text('#usda 1.0\n(\n    subLayers = [@./s.usdc@]\n)\n')
    assert usd_probe.needs_probe(layered)
    assert len(load_usd(layered)) == 12
    monkeypatch.setenv(usd_probe.PROBE_ENV, "0")
    calls = _count_children(monkeypatch)
    load_usd(crate)
    assert calls == []


def test_a_file_rewritten_while_its_stage_is_alive_reads_anew(tmp_path):
    """USD's layer registry handed back the layer as first read while a stage held it: the new
    content went unseen, and a file cut shorter crashed the reader (the fuzz long run's bus
    error, session 14)."""
    from avatarkit.gaussians.usd_read import open_usd_stage

    path = tmp_path / "r.usdc"
    save_usd(path, random_gaussians(12, seed=2))
    held = open_usd_stage(path)  # noqa: F841 -- keeps the first layer alive in the registry
    assert len(load_usd(path)) == 12
    save_usd(path, random_gaussians(5, seed=3))
    assert len(load_usd(path)) == 5
    path.write_bytes(path.read_bytes()[:200])
    with pytest.raises(FormatError, match="r.usdc"):
        load_usd(path)
