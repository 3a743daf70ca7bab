"""Plugins that break the model contract, one way each (tests/test_plugins.py). Each is a
simple model that writes `force` only (no law: the servo process gets `ModelForce`)."""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass

import numpy as np

from sim.models.api import Contact, TissueModel, option


@dataclass(frozen=True)
class Options:
    stiffness: float = option(200.0, unit="N/m", lo=1.0, hi=700.0, doc="the spring's stiffness")


class Spring(TissueModel):
    """A spring from the grasp point to the hand: keeps the contract."""

    description = "a spring to the grasp point (test plugin)"
    Options = Options
    name = "spring"

    def __init__(self, mesh, options, scene):
        self.mesh, self.k = mesh, options["stiffness"]
        self._out = np.zeros_like(mesh.vertices)

    def grasp(self, point, hand=0):
        v = self.mesh.nearest_vertex(point)
        p = tuple(float(c) for c in self.mesh.vertices[v])
        return Contact(hand=hand, vertex=int(v), point=p, normal=(0.0, 0.0, 1.0))

    def force(self, contact, d):
        k = self.k
        return (-k * d[0], -k * d[1], -k * d[2])

    def deformation(self, contacts, displacements):
        self._out[:] = 0.0
        self.frame_flops = 3.0 * len(contacts)
        for c, d in zip(contacts, displacements):
            self._out[c.vertex] = d
        return self._out


class NanForce(Spring):
    description = "force returns NaN once pulled (test plugin)"

    def force(self, contact, d):
        return (math.nan, 0.0, 0.0) if any(d) else (0.0, 0.0, 0.0)


class SlowForce(Spring):
    description = "force takes 50 microseconds (test plugin)"

    def force(self, contact, d):
        end = time.perf_counter() + 50e-6
        while time.perf_counter() < end:
            pass
        return super().force(contact, d)


class SlowBuild(Spring):
    """Keeps the contract; building it takes a second (the stability sweep builds it per case:
    a stage long enough to interrupt)."""

    description = "a spring that takes a second to build (test plugin)"

    def __init__(self, mesh, options, scene):
        time.sleep(1.0)
        super().__init__(mesh, options, scene)


class GraspRaises(Spring):
    description = "grasp raises (test plugin)"

    def grasp(self, point, hand=0):
        raise RuntimeError("no grip on this tissue")


class OtherVersion(Spring):
    api_version = 2


class BuildRaises(Spring):
    description = "build raises (test plugin)"

    def __init__(self, mesh, options, scene):
        raise RuntimeError("no tissue parameters for this brain")


class Unpicklable(Spring):
    """Writes force only and holds a lock: its copy cannot go to the servo process."""

    description = "holds a lock (test plugin)"

    def __init__(self, mesh, options, scene):
        import threading

        super().__init__(mesh, options, scene)
        self.lock = threading.Lock()


@dataclass(frozen=True)
class NeedsOptions:
    stiffness: float = option(unit="N/m", lo=1.0, hi=700.0, doc="no default: the scene must give it")


class NoDefault(Spring):
    description = "an option without a default (test plugin)"
    Options = NeedsOptions


class NotADataclass(Spring):
    class Options:
        stiffness = 200.0


@dataclass(frozen=True)
class FlagOptions:
    stiffness: float = option(200.0, unit="N/m", lo=1.0, hi=700.0)
    mirrored: bool = option(False, doc="a boolean option")
    layers: int = option(2, choices=(1, 2), doc="an integer with choices")


class Flagged(Spring):
    description = "boolean and integer-choice options (test plugin)"
    Options = FlagOptions


class WrongShape(Spring):
    """A deformation of two columns where the API asks three (and the same from the lazy surface)."""

    description = "deformation of the wrong shape (test plugin)"

    def deformation(self, contacts, displacements):
        return np.zeros((len(self.mesh.vertices), 2))


class TwoFloatForce(Spring):
    description = "force returns two numbers (test plugin)"

    def force(self, contact, d):
        return (0.0, 0.0)


@dataclass(frozen=True)
class BadDefaultOptions:
    stiffness: float = option(900.0, unit="N/m", lo=1.0, hi=700.0, doc="its default outside its own bounds")


class BadDefault(Spring):
    description = "an option whose default lies outside its bounds (test plugin)"
    Options = BadDefaultOptions


class Fem(Spring):
    """Registered under a built-in's name (tests/test_plugins.py): refused, the built-in stays."""

    description = "a plugin that calls itself fem (test plugin)"


class DiagnosticsRaise(Spring):
    description = "diagnostics raises (test plugin)"

    def diagnostics(self):
        raise RuntimeError("no counters")


class ResetRaises(Spring):
    description = "reset raises (test plugin)"

    def reset(self):
        raise RuntimeError("cannot rewind")


@dataclass(frozen=True)
class UnsetOptions:
    stiffness: float = option(200.0, unit="N/m", lo=1.0, hi=700.0)
    k0: float | None = option(None, unit="N/m", doc="an option left unset: the model works its own value out")


class Unset(Spring):
    description = "an option whose default is unset, None (test plugin)"
    Options = UnsetOptions


class ForceRaises(Spring):
    description = "force raises an exception (test plugin)"

    def force(self, contact, d):
        raise RuntimeError("no force today")


class ForceRaisesNear(Spring):
    description = "force raises an exception under 1 mm of pull, not at zero (test plugin)"

    def force(self, contact, d):
        if 0.0 < math.sqrt(sum(x * x for x in d)) < 1e-3:
            raise ValueError("no force under 1 mm")
        return super().force(contact, d)


class NanForceScaled(NanForce):
    """NanForce for the discrimination task: it scales its stiffness (and still renders NaN)."""

    description = "force returns NaN once pulled, stiffness scaled (test plugin)"
    scales_stiffness = True

    def with_stiffness(self, scale):
        out = copy.copy(self)
        out.k = self.k * scale
        out._out = np.zeros_like(self.mesh.vertices)
        return out
