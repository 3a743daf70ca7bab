"""Skill profiles of synthetic participants by group: `[synthetic.groups.NAME]`.

A protocol with `design.groups` may give each group's synthetic operator a profile: tremor,
speed, overshoot of the target, how the operator holds back near the safe force limit, learning
over trials towards a plateau, and a per-participant spread. A key left out keeps the default,
and the default profile is the synthetic participant without a profile (docs/synthetic.md,
"Skill profiles for groups"). `check_skills` reads and checks the section for
`studyctl.protocol.check_protocol`; `SkillProfile.individual` gives one participant's values and
`Skill.at(trial)` their values on a trial.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, fields

from analysis.study.fields import FieldKind
from sim.tomltable import TableReader

# key -> (lowest, highest, default, unit); a default None means "as without a profile"
KEYS: dict[str, tuple[float, float, float | None, str]] = {
    "tremor_mm": (0.0, 2.0, None, "mm per axis"),  # None: the participant's own draw, 0.1-0.4 mm
    "speed": (0.25, 4.0, 1.0, "times the scene's pull speed"),
    "overshoot": (0.0, 1.0, 0.0, "fraction of the target distance"),
    "force_restraint": (0.0, 1.0, 0.0, "0: ignores the safe limit, 1: holds back most"),
    "learning": (0.0, 100.0, 0.0, "trials to halve the gap to the plateau; 0: no learning"),
    "plateau_tremor_mm": (0.0, 2.0, None, "mm per axis"),  # None: tremor_mm (no change over trials)
    "plateau_speed": (0.25, 4.0, None, "times the scene's pull speed"),  # None: speed
    "plateau_overshoot": (0.0, 1.0, None, "fraction of the target distance"),  # None: overshoot
    "spread": (0.0, 1.0, 0.0, "log-sd across participants"),
}
PLATEAUS = {"plateau_tremor_mm": "tremor_mm", "plateau_speed": "speed", "plateau_overshoot": "overshoot"}


@dataclass(frozen=True)
class SkillProfile:
    """A group's synthetic operator (the group's median participant on their first trial, and
    the plateau it learns towards). Units and ranges in `KEYS`."""

    tremor_mm: float | None = None
    speed: float = 1.0
    overshoot: float = 0.0
    force_restraint: float = 0.0
    learning: float = 0.0
    plateau_tremor_mm: float | None = None
    plateau_speed: float | None = None
    plateau_overshoot: float | None = None
    spread: float = 0.0

    def individual(self, code: str, seed: int) -> Skill:
        """One participant's profile: each value times exp(spread * z), z standard normal drawn
        from a generator of its own (seed and code), the same factor for the first trial and the
        plateau; force restraint spread on the logit scale (0 and 1 stay). With spread 0 the
        group's values."""
        rng = random.Random(f"skill:{seed}:{code}")
        zt, zs, zo, zr = (rng.gauss(0.0, 1.0) for _ in range(4))
        ft, fs, fo = (math.exp(self.spread * z) for z in (zt, zs, zo))
        t0 = None if self.tremor_mm is None else self.tremor_mm * ft
        t1 = None if self.tremor_mm is None else (self.tremor_mm if self.plateau_tremor_mm is None else self.plateau_tremor_mm) * ft
        s1 = self.speed if self.plateau_speed is None else self.plateau_speed
        o1 = self.overshoot if self.plateau_overshoot is None else self.plateau_overshoot
        r = self.force_restraint
        if 0.0 < r < 1.0 and self.spread:
            r = 1.0 / (1.0 + math.exp(-(math.log(r / (1.0 - r)) + self.spread * zr)))
        clip = lambda v, key: min(KEYS[key][1], max(KEYS[key][0], v))  # noqa: E731
        return Skill(tremor_mm=t0, speed=clip(self.speed * fs, "speed"), overshoot=clip(self.overshoot * fo, "overshoot"),
                     force_restraint=r, learning=self.learning, plateau_tremor_mm=t1,
                     plateau_speed=clip(s1 * fs, "speed"), plateau_overshoot=clip(o1 * fo, "overshoot"))


@dataclass(frozen=True)
class Skill:
    """One synthetic participant's skill (from `SkillProfile.individual`): first-trial values,
    plateaus and the learning half-life in trials."""

    tremor_mm: float | None
    speed: float
    overshoot: float
    force_restraint: float
    learning: float
    plateau_tremor_mm: float | None
    plateau_speed: float
    plateau_overshoot: float

    def at(self, trial: int) -> tuple[float | None, float, float]:
        """(tremor mm or None, speed, overshoot) on trial `trial` (0: the first): each value
        plateau + (first - plateau) * 2 ** (-trial / learning)."""
        w = 2.0 ** (-trial / self.learning) if self.learning > 0 else 1.0
        tremor = None if self.tremor_mm is None else self.plateau_tremor_mm + (self.tremor_mm - self.plateau_tremor_mm) * w
        return (tremor, self.plateau_speed + (self.speed - self.plateau_speed) * w,
                self.plateau_overshoot + (self.overshoot - self.plateau_overshoot) * w)

    def values(self) -> dict[str, float]:
        """The values by name (`skill_*` in `synthetic_traits`; a tremor of the participant's own
        draw is left out: it is `tremor_m`)."""
        return {f"skill_{f.name}": float(getattr(self, f.name)) for f in fields(self) if getattr(self, f.name) is not None}


def check_skills(data: dict, groups: str | None, fields_: list, c: TableReader) -> dict[str, SkillProfile]:
    """[synthetic.groups.NAME] tables, each problem added to the protocol file's reader `c` (FILE:LINE:
    field: message, naming what is allowed): a group that is not a value of design.groups' field,
    the section without design.groups, an unknown key, a value out of range."""
    raw = data.get("synthetic")
    if raw is None:
        return {}
    if not isinstance(raw, dict):
        c.error("synthetic", "must be a table: [synthetic.groups.NAME], one per group")
        return {}
    tables = raw.get("groups")
    if tables is None:
        return {}
    if not isinstance(tables, dict) or not all(isinstance(t, dict) for t in tables.values()):
        c.error("synthetic.groups", "must be tables, one per group: [synthetic.groups.NAME] with tremor_mm = ..., speed = ...")
        return {}
    field = next((f for f in fields_ if f.name == groups), None) if groups else None
    if groups is None:  # named at the first group's table (the file has no [synthetic.groups] line of its own)
        where = f"synthetic.groups.{next(iter(tables))}" if tables else "synthetic.groups"
        line = c.loc.line(where)
        c.problems.append((c.path, line, f"{c.path}:{line}: synthetic.groups: needs design.groups: the choice field whose values are the groups"))
        return {}
    values = field.values if field is not None and field.kind == FieldKind.CHOICE else None  # a bad design.groups is reported there
    out: dict[str, SkillProfile] = {}
    for name, t in tables.items():
        sec = f"synthetic.groups.{name}"
        if values is not None and name not in values:
            c.error(sec, f"not a value of design.groups field {groups}; allowed: {', '.join(values)}")
            continue
        ok = True
        for key in t:
            if key not in KEYS:
                c.error(f"{sec}.{key}", f"unknown key; allowed: {', '.join(KEYS)}")
                ok = False
        got = {}
        r = c.sub(t, f"{sec}.")
        for key, (lo, hi, default, _) in KEYS.items():
            n = len(c.problems)
            v = r.number(key, default=default, lo=lo, hi=hi)
            ok = ok and len(c.problems) == n
            got[key] = v
        for key, base in PLATEAUS.items():
            if key in t and not t.get("learning"):
                c.error(f"{sec}.{key}", f"a plateau needs learning > 0 (trials to halve the gap from {base} to it)")
                ok = False
        if "plateau_tremor_mm" in t and "tremor_mm" not in t:
            c.error(f"{sec}.plateau_tremor_mm", "needs tremor_mm: the group's tremor on the first trial")
            ok = False
        if ok:
            out[name] = SkillProfile(**got)
    return out
