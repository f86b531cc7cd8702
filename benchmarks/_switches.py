"""Module switches set from a benchmark's command line: `--set recon.multiview.RELABEL_CONNECTED=None`.

The library's switches are module constants read at call time (docs/development.md, "Module
switches"), so setting one before a build takes effect. A build that runs in a process of its
own (`build_video.py`'s `_in_own_process`) must set them again there: hand it the texts.
"""
from __future__ import annotations

import ast
import importlib


def parse_switch(text: str):
    """"pkg.module.NAME=value" -> (module object, NAME, value): the module under `avatarkit.`,
    NAME an existing UPPERCASE constant of it, value a Python literal (None, 0.15, "band",
    True) or else the bare text as a string. ValueError naming what is wrong."""
    target, eq, raw = text.partition("=")
    mod_name, _, name = target.strip().rpartition(".")
    if not eq or not mod_name or not name:
        raise ValueError(f"--set {text!r}: expected module.NAME=value, e.g. recon.multiview.SCALP_FILL=False")
    if not name.isupper():
        raise ValueError(f"--set {text!r}: {name} is not a module switch (UPPERCASE constant)")
    full = mod_name if mod_name.startswith("avatarkit.") else "avatarkit." + mod_name
    try:
        module = importlib.import_module(full)
    except ImportError as e:
        raise ValueError(f"--set {text!r}: no module {full} ({e})") from None
    if not hasattr(module, name):
        raise ValueError(f"--set {text!r}: {full} has no {name}")
    try:
        value = ast.literal_eval(raw.strip())
    except (ValueError, SyntaxError):
        value = raw.strip()
    return module, name, value


def apply_switches(texts) -> list[str]:
    """Set every `--set` text's switch; returns "module.NAME = value" lines to print."""
    done = []
    for text in texts or ():
        module, name, value = parse_switch(text)
        setattr(module, name, value)
        done.append(f"{module.__name__}.{name} = {value!r}")
    return done
