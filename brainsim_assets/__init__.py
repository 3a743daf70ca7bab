"""Where the shipped files are: the brain surface, the scene, the protocol, the model
parameter files, the stiffness field and the observer's truth.

In a checkout they are the repository's top-level `protocols/` and `data/` (the source of
truth); in an installed wheel the same two folders are package data of this package
(`brainsim_assets/protocols`, `brainsim_assets/data`, mapped in pyproject.toml), so the
relative paths inside the TOML files (a scene's `../../data/...`) hold in both. A file the user
names on the command line always wins over these defaults.
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path


def root() -> Path:
    """The folder that holds `protocols/` and `data/`."""
    here = Path(str(files(__name__)))
    if (here / "protocols").is_dir():  # installed: the package data beside this file
        return here
    return here.parent  # a checkout (or an editable install): the repository's own folders


def version() -> str:
    """The one version: the installed package's metadata (pyproject.toml's `version`); in a
    checkout that was never installed, read from pyproject.toml itself."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as _version

    try:
        return _version("brainsim-study")
    except PackageNotFoundError:
        import tomllib

        try:
            return tomllib.loads((root() / "pyproject.toml").read_text())["project"]["version"]
        except (OSError, KeyError, tomllib.TOMLDecodeError):
            return "unknown"


def path(relative: str) -> Path:
    """A shipped file, e.g. ``path("protocols/scenes/brain_pull.toml")``."""
    return root() / relative


__all__ = ["root", "path", "version"]
