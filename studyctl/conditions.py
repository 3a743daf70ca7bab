"""A study's conditions: the scene's model as each `[conditions.NAME]` table of the protocol
configures it, and the fully resolved configuration stored with every session (JSON and its
SHA-256). A condition listed by a model name alone (`design.conditions = ["fem", ...]`, the
old form) is the scene's own configuration of that model."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

from brainsim_assets import version as _version
from sim.models.registry import model_class, provenance
from sim.scene import Scene, configure, load_scene
from sim.tomlfile import Locator

SOFTWARE_VERSION = f"brainsim-study {_version()}"  # stored with each session and rig profile

_SCENES: dict = {}  # (scene file, resolved configuration's hash, device) -> Scene: models are built once per process


def condition_scene_spec(protocol, name: str, spec=None):
    """The scene spec (`sim.scene.SceneSpec`) whose default model is condition `name`; `spec`:
    the protocol's scene, already loaded. Raises SceneError naming the protocol's lines."""
    spec = spec if spec is not None else load_scene(protocol.scene)
    table = protocol.condition_tables.get(name)
    if table is None:  # the old form: the scene's own configuration of the model
        spec.model_spec(name)  # raises, naming what the scene configures
        return dataclasses.replace(spec, model=name)
    return configure(spec, table, protocol.path, Locator(protocol.text), f"conditions.{name}.")


def condition_scene(protocol, condition: str, device: str):
    """The protocol's scene for `condition` (its model as the protocol configures it), with every
    hand on `device` (built once per process, reused)."""
    spec = condition_scene_spec(protocol, condition)
    key = (str(protocol.scene), config_sha256(resolved_config(condition, spec)), device)
    if key not in _SCENES:
        _SCENES[key] = Scene(spec).with_device(device)
    return _SCENES[key]


def condition_configs(protocol, names) -> dict[str, dict]:
    """Each condition's fully resolved configuration, stored with the session: exports and
    reports show it, the participant never."""
    spec = load_scene(protocol.scene)
    return {c: resolved_config(c, condition_scene_spec(protocol, c, spec)) for c in names}


def scene_itself(protocol):
    """The protocol's scene as its file configures it, no condition applied: what the synthetic
    observer's truth (analysis/verification/truth.py) and the force reference are made for."""
    return Scene(load_scene(protocol.scene))


def _plain(value):
    if isinstance(value, Path):  # a file's content, not where it lies on this machine
        return {"file": value.name, "sha256": hashlib.sha256(value.read_bytes()).hexdigest()}
    if dataclasses.is_dataclass(value):
        return {k: _plain(v) for k, v in dataclasses.asdict(value).items()}
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in sorted(value.items())}
    return value


def resolved_config(name: str, spec) -> dict:
    """What condition `name` runs: the model with every option, the material (JSON-able)."""
    m = spec.model_spec()
    material = _plain(spec.material)
    if material.get("law_source") not in (None, "", "inline"):  # the law file's content, as for every other file
        material["law_source"] = _plain(Path(material["law_source"]))
    for truth_only in ("white_matter", "white_matter_source", "pia_arachnoid"):
        # the reference's body, not the models': absent, a configuration is what it was before it existed
        if material.get(truth_only) in (None, ""):
            material.pop(truth_only, None)
    if isinstance(material.get("pia_arachnoid"), dict):  # its measured spread is the truth's band, not a model's input
        material["pia_arachnoid"].pop("mu_spread", None)
    if material.get("white_matter_source"):
        material["white_matter_source"] = _plain(Path(material["white_matter_source"]))
    out = {"condition": name, "model": m.name, "material": material,
           # what else the forces depend on: the scene file itself (any edit is a new configuration),
           # the surface, the clamp, the loop rates
           "scene": _plain(spec.path), "mesh": _plain(spec.mesh_path), "fixed": _plain(spec.fixed),
           "servo_rate_hz": spec.servo_rate_hz, "visual_rate_hz": spec.visual_rate_hz}
    out |= {k: _plain(v) for k, v in model_class(m.name).configuration(m.options).items()}
    if (source := provenance(m.name)) is not None:  # a lab's own model: which code ran
        out["plugin"] = source
    return out


def config_json(config: dict) -> str:
    return json.dumps(config, sort_keys=True, separators=(",", ":"))


def config_sha256(config: dict) -> str:
    return hashlib.sha256(config_json(config).encode()).hexdigest()
