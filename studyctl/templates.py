"""`studyctl protocol new`: a lab's own protocol and scene, written from a shipped example of its
kind into a folder of its own, with every path in them resolving from there: the protocol names
its scene beside it, the scene names the shipped files it uses as `shipped:PATH` (never an
absolute path into one install, which breaks when the venv moves or the folder is shared)."""

from __future__ import annotations

import os
import re
from pathlib import Path

from analysis.errors import InputError
from brainsim_assets import path as asset
from brainsim_assets import root
from sim.tomltable import SHIPPED
from studyctl.outputs import Staged
from studyctl.protocol import check_protocol

KINDS = {  # kind -> the shipped protocol it starts from, and what it is
    "yes_no": ("brain_pull_2015.toml", "the paper's study: yes/no questions after each model"),
    "rating": ("plate_spring_variants.toml", "ratings (7-point), a standard instrument (SUS) and a choice at the end"),
    "discrimination": ("stiffness_jnd.toml", "two-interval stiffness discrimination (QUEST+), Weber fractions per condition"),
    "validity": ("construct_validity.toml", "construct validity: groups of experience, performance metrics, targets"),
}
_RELATIVE = re.compile(r'"((?:\.\./)+[^"]+)"')
_NAME = re.compile(r"^[a-z][a-z0-9_]{0,63}$")


def new_protocol(kind: str, out_dir: str | Path, name: str | None = None, force: bool = False) -> dict:
    """Write OUT/protocol.toml (the `kind`'s shipped example, renamed `name`) and OUT/scene.toml
    (its scene, the relative paths to the shipped surface, material and model files made
    `shipped:PATH`); check the protocol. Both or neither (studyctl/outputs.py): an existing file is
    refused unless `force`, and a failed write (a full disk) leaves nothing behind. Returns what
    was written (`replaced`: the files `force` overwrote)."""
    if kind not in KINDS:
        raise InputError(f"--kind: {kind!r} is not a kind; allowed: {', '.join(KINDS)}")
    if name is not None and not _NAME.match(name):
        raise InputError(f"--name: {name!r}: lower-case letters, digits and _ (starting with a letter), at most 64")
    out = Path(out_dir)
    protocol_path, scene_path = out / "protocol.toml", out / "scene.toml"
    target = Staged(out, force, folder=True, expect=(protocol_path.name, scene_path.name))
    source = asset(f"protocols/{KINDS[kind][0]}")
    text = source.read_text()
    scene_rel = re.search(r'^scene\s*=\s*"([^"]+)"', text, re.M).group(1)
    # normalised, not resolved: a folder of the install that is a link stays inside it
    shipped_scene = Path(os.path.normpath(source.parent / scene_rel))
    shipped = Path(os.path.normpath(root()))
    scene_text = _RELATIVE.sub(
        lambda m: f'"{SHIPPED}{Path(os.path.normpath(shipped_scene.parent / m.group(1))).relative_to(shipped).as_posix()}"',
        shipped_scene.read_text())
    text = re.sub(r'^scene\s*=\s*"[^"]+"(.*)$', r'scene = "scene.toml"\1', text, count=1, flags=re.M)
    if name is not None:
        text = re.sub(r'^name\s*=\s*"[^"]+"', f'name = "{name}"', text, count=1, flags=re.M)
    header = (f"# Written by `studyctl protocol new --kind {kind}` from the shipped {KINDS[kind][0]}: "
              f"{KINDS[kind][1]}.\n# Edit freely; `studyctl protocol validate protocol.toml` checks it (docs/study.md lists every key).\n")
    try:
        with target as tmp:  # checked where it is written: the scene's path is relative to the protocol
            (tmp / scene_path.name).write_text(
                f"# Written by `studyctl protocol new` from the shipped {shipped_scene.name}; shipped files named {SHIPPED}PATH.\n"
                + scene_text)
            (tmp / protocol_path.name).write_text(header + text)
            _, problems = check_protocol(tmp / protocol_path.name)
            if problems:  # a bug of the template, never the user's: nothing left behind
                raise InputError(f"{protocol_path}: the template does not validate: {problems[0].replace(str(tmp), str(out))}")
    except OSError as exc:
        raise InputError(f"{out}: cannot write the protocol: {exc.strerror or exc}; nothing was written") from None
    return {"kind": kind, "from": str(source), "protocol": str(protocol_path), "scene": str(scene_path),
            "name": re.search(r'^name\s*=\s*"([^"]+)"', text, re.M).group(1), "replaced": [str(p) for p in target.replaced]}
