"""The README's CLI overview names only commands that exist (docs checked by tests)."""

import re

import click

from studyctl.cli import cli
from tests.conftest import ROOT


def test_every_readme_command_exists():
    lines = [ln.strip() for ln in (ROOT / "README.md").read_text().splitlines() if ln.strip().startswith("studyctl ")]
    assert len(lines) > 15
    for line in lines:
        cmd: click.Command = cli
        for word in line.split()[1:]:
            if not isinstance(cmd, click.Group) or not re.fullmatch(r"[a-z0-9][a-z0-9-]*", word):
                break
            assert word in cmd.commands, f"README: {line!r}: no command {word!r}"
            cmd = cmd.commands[word]
        # `schedule` is a command with subcommands (`schedule cancel`)
        assert not isinstance(cmd, click.Group) or cmd.invoke_without_command, f"README: {line!r} names a group, not a command"
        options = {o for p in cmd.params for o in getattr(p, "opts", [])}
        for opt in re.findall(r"(?<![\w-])(--[a-z][a-z0-9-]*)", line):
            assert opt in options, f"README: {line!r}: {opt} is not an option of {cmd.name}"
