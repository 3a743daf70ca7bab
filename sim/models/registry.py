"""Which tissue models are installed: the entry-point group ``brainsim.models`` (name -> class;
the three built-in models register there too, in pyproject.toml) and ``"package.module:Class"``
names for a model on the Python path. A model that does not load (its import fails, its class is
missing, it declares another API version, an option's default lies outside its own bounds) is one
line naming it and the cause; the others load. Names are spelt with `_` or `-` alike
(`plate-spring` is `plate_spring`). A plugin may not take a name already taken: a built-in's name
stays the built-in's, and a name two plugins register is neither's; each refusal is a line."""

from __future__ import annotations

import functools
import hashlib
import inspect
import re
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

from sim.errors import SimError
from sim.models.api import API_VERSION, TissueModel, declaration_problem, default_problem, options_of

GROUP = "brainsim.models"
HOME = "brainsim-study"  # the distribution of the built-in models
PATH_NAME = re.compile(r"^[A-Za-z_][\w.]*:[A-Za-z_]\w*$")  # package.module:Class


class ModelLoadError(SimError):
    """A model that cannot be used: the message names it and the cause, in one line."""


@dataclass(frozen=True)
class ModelInfo:
    name: str
    target: str  # "package.module:Class"
    distribution: str | None  # None: a "package.module:Class" on the Python path
    version: str | None

    @property
    def builtin(self) -> bool:
        return self.distribution == HOME


def canonical(name):
    """`name` as the registry keys it: a registered name with `-` spelt `_` (`plate-spring` is
    `plate_spring`); a "package.module:Class" name, or anything not a string, unchanged."""
    if not isinstance(name, str) or ":" in name:
        return name
    return name.replace("-", "_")


def _scan() -> tuple[dict[str, ModelInfo], list[str]]:
    """(the registered models by canonical name, one line per registration refused). The
    built-in models are read first and keep their names; a plugin registering a built-in's name,
    or a name another plugin registers too, is refused."""
    found: dict[str, list[ModelInfo]] = {}
    for ep in metadata.entry_points(group=GROUP):
        dist = ep.dist.name if ep.dist is not None else None
        version = ep.dist.version if ep.dist is not None else None
        i = ModelInfo(canonical(ep.name), ep.value, dist, version)
        if i not in found.setdefault(i.name, []):  # one distribution seen twice on the path is one registration
            found[i.name].append(i)
    out: dict[str, ModelInfo] = {}
    refused: list[str] = []
    for name, regs in found.items():
        home = [i for i in regs if i.builtin]
        others = [i for i in regs if not i.builtin]
        if home:
            out[name] = home[0]
            refused += [f"model {name!r} (from {_source(i)}): refused: {name!r} is a built-in model's name, and the built-in "
                        f"stays; register the plugin under another name" for i in others]
        elif len(others) == 1:
            out[name] = others[0]
        else:
            froms = " and ".join(sorted(_source(i) for i in others))  # the same line whatever order the entry points come in
            refused.append(f"model {name!r}: refused: registered by {froms}; neither loads until one is uninstalled or renamed")
    return out, refused


@functools.cache
def _registered() -> tuple[dict[str, ModelInfo], tuple[str, ...]]:
    out, refused = _scan()
    return out, tuple(refused)


def entry_points() -> dict[str, ModelInfo]:
    """The registered models, by canonical name (refused registrations left out: `refusals`)."""
    return _registered()[0]


def refusals() -> list[str]:
    """One line per registration the registry refused (a name taken by a built-in, or by two plugins)."""
    return list(_registered()[1])


def names() -> list[str]:
    """Every registered name (loaded or not), sorted."""
    return sorted(entry_points())


def is_model_name(name) -> bool:
    """`name` could name a model: registered (either spelling), or of the form package.module:Class."""
    return isinstance(name, str) and (canonical(name) in entry_points() or bool(PATH_NAME.match(name)))


def info(name: str) -> ModelInfo:
    key = canonical(name)
    if key in entry_points():
        return entry_points()[key]
    if PATH_NAME.match(key):
        return ModelInfo(key, key, None, None)
    raise _unknown(name)


def _unknown(name) -> ModelLoadError:
    """A name nothing registers, said as it was typed (not as the registry keys it)."""
    available = ", ".join(names()) or "none"
    return ModelLoadError(f"unknown model {name!r}; installed: {available} (or name a class as \"package.module:Class\")")


def model_class(name: str) -> type:
    """The class of model `name` (either spelling), checked against the API. Raises ModelLoadError."""
    info(name)  # a name nothing registers is refused as it was typed
    return _model_class(canonical(name))


@functools.cache
def _model_class(name: str) -> type:
    i = info(name)
    where = f"model {name!r}" + (f" (from {i.distribution} {i.version})" if i.distribution and not i.builtin else "")
    module_name, _, attr = i.target.partition(":")
    try:
        module = metadata.EntryPoint(name, module_name, GROUP).load()  # a module loads as an entry point's does
    except Exception as exc:  # a plugin's import may fail in any way: one line, the others load
        raise ModelLoadError(f"{where}: cannot import {module_name}: {type(exc).__name__}: {exc}") from None
    cls = getattr(module, attr, None) if attr else None
    if cls is None:
        raise ModelLoadError(f"{where}: {module_name} has no class {attr!r}")
    if not (inspect.isclass(cls) and issubclass(cls, TissueModel)):
        raise ModelLoadError(f"{where}: {i.target} is not a subclass of sim.models.api.TissueModel")
    if cls.api_version != API_VERSION:
        raise ModelLoadError(f"{where}: declares model API version {cls.api_version!r}; this brainsim runs version {API_VERSION}")
    if (problem := declaration_problem(cls) or default_problem(cls)) is not None:
        raise ModelLoadError(f"{where}: {problem}")
    return cls


def installed() -> tuple[dict[str, type], list[str]]:
    """(the models that load, by name; one line per registered model that does not)."""
    ok, problems = {}, refusals()
    for name in names():
        try:
            ok[name] = model_class(name)
        except ModelLoadError as exc:
            problems.append(str(exc))
    return ok, problems


def plugins(models) -> list[str]:
    """The names among `models` that come from outside brainsim, sorted."""
    return sorted(name for name in models if not info(name).builtin)


def source_sha256(cls) -> str:
    """SHA-256 of the source of the package (or module) that holds `cls`: its .py files, by
    relative path and content."""
    module = inspect.getmodule(cls)
    path = Path(inspect.getfile(module))
    top = module.__name__.split(".")[0]
    root = path
    for _ in range(module.__name__.count(".") + (1 if path.name == "__init__.py" else 0)):
        root = root.parent
    files = sorted(root.rglob("*.py")) if root.is_dir() and root.name == top else [path]
    h = hashlib.sha256()
    for f in files:
        h.update(str(f.relative_to(root.parent)).encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()


def provenance(name: str) -> dict | None:
    """Where a model outside brainsim comes from (stored with a study's condition): its
    distribution, version and the SHA-256 of its source; None for the built-in models."""
    i = info(name)
    if i.builtin:
        return None
    name = canonical(name)
    return {"target": i.target, "distribution": i.distribution, "version": i.version, "source_sha256": source_sha256(model_class(name))}


def _source(i: ModelInfo) -> str:
    return f"{i.distribution} {i.version}" if i.distribution else "the Python path"


def describe(name: str) -> dict:
    """What `studyctl model describe` prints. Raises ModelLoadError."""
    cls, i = model_class(name), info(name)
    name = canonical(name)
    capabilities = {"stiffness scaling": bool(cls.scales_stiffness)}  # declared; the others are seen when it runs
    return {"name": name, "class": i.target, "distribution": i.distribution, "version": i.version, "source": _source(i),
            "builtin": i.builtin, "api_version": cls.api_version, "description": cls.description,
            "material_keys": list(cls.material_keys), "capabilities": capabilities,
            "options": [o.__dict__ for o in options_of(cls)]}


def describe_installed() -> tuple[list[dict], list[str]]:
    """Every installed model that loads, described; one line per one that does not."""
    models, problems = installed()
    rows = [{"name": n, "source": _source(info(n)), "builtin": info(n).builtin, "description": c.description,
             "scales_stiffness": bool(c.scales_stiffness)} for n, c in models.items()]
    return rows, problems
