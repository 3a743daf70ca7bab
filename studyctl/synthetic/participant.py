"""Synthetic participants: a motor model and an answer model, both driven by the simulator.

A synthetic participant is a model, not data, and everything it produces is labelled
synthetic. See docs/synthetic.md for the model and its parameters.

- Motor model: for each trial and hand, a minimum-jerk pull along the surface (the scene's
  scripted pull, scaled per participant in distance and duration), physiological tremor
  (8-12 Hz, 0.1-0.4 mm per axis), and the participant's own hand impedance, which the
  rendered force acts on.
- Answer model: the observer (studyctl/synthetic/observer.py): P(yes) for a question after a condition
  is a logistic function of what this participant perceived of its trials against the
  converged reference (force within their JND of what they expect, deformation latency,
  vibration, safety events) and their bias. No outcome is set per model.
- Skill: a hand whose scene gives it a target is pulled to the target, beyond
  it by the participant's overshoot and back, and held there; a protocol's
  `[synthetic.groups.NAME]` gives a group's tremor, speed, overshoot, force restraint and
  learning (studyctl/synthetic/skill.py). Without a profile and a target, the scene's pull as before.
"""

from __future__ import annotations

import dataclasses
import math
import random
from dataclasses import dataclass

from analysis.errors import StoreError
from analysis.study.questions import SESSION, Kind
from sim.devices.simulated import HandImpedance
from studyctl.store.participant_fields import group_of
from studyctl.synthetic.observer import (
    DEFAULT,
    DiscriminationTraits,
    ObserverParams,
    ObserverTraits,
    features,
    judged_answer,
    logit,
    stiffer_answer,
    summarise,
)
from studyctl.synthetic.skill import Skill, SkillProfile

MAX_SYNTHETIC = 1000  # participants per `synth` call: a study, not a stress test (the paper had 35)
CORRECTION_DELAY = 0.2  # s from the end of an overshooting movement to the start of the correction (a visual reaction time)
CORRECTION_TIME = 0.5  # the corrective movement's duration, times the first movement's
HOLD_MARGIN = 1.0  # s a target-pursuing hand keeps its grasp beyond the movement and the target's hold time

def skill_for(store, protocol, code: str) -> SkillProfile | None:
    """The skill profile of the participant's group (`[synthetic.groups.NAME]`), None without one."""
    group = group_of(store, protocol, code) if protocol.skills else None
    return protocol.skills.get(group) if group is not None else None


@dataclass(frozen=True)
class SyntheticParticipant:
    code: str
    seed: int
    pull_scale: float  # times the scene's pull distance
    time_scale: float  # times the scene's pull duration
    tremor_m: float
    tremor_hz: float
    stiffness: float  # hand stiffness, N/m
    traits: ObserverTraits  # how they perceive (studyctl/synthetic/observer.py)
    discrimination: DiscriminationTraits  # how finely they tell stiffness apart (the discrimination task)
    skill: Skill | None = None  # their group's skill profile, spread to them (studyctl/synthetic/skill.py); None: no profile

    @classmethod
    def draw(cls, code: str, seed: int, profile: SkillProfile | None = None) -> SyntheticParticipant:
        """The participant of this code and seed; `profile` (their group's, `skill_for`) gives
        their skill. The other traits do not depend on it."""
        rng = random.Random(f"participant:{seed}:{code}")
        return cls(
            code=code, seed=seed,
            pull_scale=rng.uniform(0.8, 1.2), time_scale=rng.uniform(0.8, 1.3),
            tremor_m=rng.uniform(0.1e-3, 0.4e-3), tremor_hz=rng.uniform(8.0, 12.0),
            stiffness=rng.uniform(200.0, 500.0), traits=ObserverTraits.draw(code, seed),
            discrimination=DiscriminationTraits.draw(code, seed),
            skill=profile.individual(code, seed) if profile is not None else None,
        )

    def trait_values(self) -> dict[str, float]:
        """Every generating trait by name (stored with the study: `synthetic_traits`); a skill's
        values as `skill_*` (first trial and plateau)."""
        out = {k: float(getattr(self, k)) for k in ("pull_scale", "time_scale", "tremor_m", "tremor_hz", "stiffness")}
        out |= {f"observer_{k}": float(v) for k, v in dataclasses.asdict(self.traits).items()}
        out |= {f"stiffness_{k}": float(v) for k, v in dataclasses.asdict(self.discrimination).items()}
        return out | (self.skill.values() if self.skill is not None else {})

    def operators(self, scene, trial: int, model: str) -> list:
        """This participant's pulls for one trial, varied per trial and hand: the scene's pull,
        or, for a hand with a target, to the target (beyond it by the overshoot and back) and
        held there, with the skill's tremor, speed and force restraint on this trial."""
        rng = random.Random(f"trial:{self.seed}:{self.code}:{model}:{trial}")
        tremor_mm, speed, overshoot = self.skill.at(trial if isinstance(trial, int) else 0) if self.skill else (None, 1.0, 0.0)
        restraint = self.skill.force_restraint if self.skill else 0.0
        tremor_m = self.tremor_m if tremor_mm is None else tremor_mm * 1e-3
        targets = scene.targets() if any(h.target is not None for h in scene.spec.hands) else [None] * len(scene.spec.hands)
        out = []
        for i in range(len(scene.spec.hands)):
            base = scene.spec.hands[i].script(scene.mesh)
            s = self.pull_scale * rng.uniform(0.9, 1.1)
            mass = 0.2
            damping = 2 * 0.7 * math.sqrt(self.stiffness * mass)
            script = dataclasses.replace(
                base,
                pull=tuple(s * c for c in base.pull),
                pull_time=base.pull_time * self.time_scale * rng.uniform(0.9, 1.1) / speed,
                tremor_m=tremor_m, tremor_hz=self.tremor_hz,
                tremor_phase=tuple(rng.uniform(0, 2 * math.pi) for _ in range(3)),
                impedance=HandImpedance(mass_kg=mass, stiffness_n_per_m=self.stiffness, damping_ns_per_m=damping),
            )
            out.append(script if targets[i] is None else pursue(script, targets[i], overshoot, restraint))
        return out


def pursue(script, target, overshoot: float, restraint: float = 0.0):
    """`script` made to pursue `target` (a `sim.targets.HandTarget`): from the grasp to the
    target times (1 + overshoot) along its direction in the script's pull time, then, after
    `CORRECTION_DELAY`, back to the target in `CORRECTION_TIME` of it, both minimum jerk; held
    until the target's hold time and `HOLD_MARGIN` have passed (at least the script's own
    release); holding back near the target's safe force by `restraint`."""
    d, u = target.spec.distance, target.direction
    end = script.pull_start + script.pull_time
    back = {}
    if overshoot > 0:
        back = {"back": tuple(-overshoot * d * c for c in u), "back_start": end + CORRECTION_DELAY,
                "back_time": CORRECTION_TIME * script.pull_time}
        end = back["back_start"] + back["back_time"]
    return dataclasses.replace(
        script, pull=tuple((1.0 + overshoot) * d * c for c in u), **back,
        release_at=max(script.release_at, end + target.spec.hold + HOLD_MARGIN),
        restraint=restraint, safe_force=target.spec.safe_force if restraint > 0 else math.inf)


class SyntheticAnswers:
    """Answers from the observer (studyctl/synthetic/observer.py), drawn with a seeded generator
    (labelled synthetic). `features_of(model)` gives what was perceived, for the database."""

    source = "synthetic"

    def __init__(self, participant: SyntheticParticipant, truth, mesh, params: ObserverParams = DEFAULT, rig: dict | None = None):
        self.participant = participant
        self.truth, self.mesh, self.params = truth, mesh, params
        self.rig = rig or {}  # condition -> the rig's frame time, ms (studyctl/synthetic/rig.py); a condition without one: the flop model
        self._feats: dict[str, dict] = {}

    def _summaries(self, model: str, results: list) -> list:
        out = [summarise(r, self.truth, self.mesh, self.params) for r in results]
        if model in self.rig:
            out = [dataclasses.replace(s, frame_ms=self.rig[model]) for s in out]
        return out

    def begin(self, label: str) -> None:
        pass

    def features_of(self, model: str, results: list) -> dict:
        if model not in self._feats:
            summaries = self._summaries(model, results)
            if model not in self.rig and any(math.isnan(s.frame_flops) for s in summaries):  # a trace from before work counts: no latency to judge
                raise StoreError(f"condition {model}: a stored trial has no frame work counts (recorded by an older version, or its "
                                 "model counts none: set frame_flops in deformation, docs/models.md); the synthetic observer cannot "
                                 "judge its latency; start the participant's session afresh, or give the study a rig profile")
            self._feats[model] = features(summaries, self.participant.traits, self.params)
        return self._feats[model]

    def discriminate(self, task, model: str, context: dict) -> int:
        """Which of the trial's two intervals felt stiffer (1 or 2), from their traces
        (`studyctl.synthetic.observer.stiffer_answer`), drawn with a generator seeded by the trial."""
        who = self.participant
        rng = random.Random(f"discrimination:{who.seed}:{who.code}:{model}:{task.index}:{context['trial']}")
        return stiffer_answer(context["intervals"], who.discrimination, rng.random, lambda: rng.gauss(0.0, 1.0), self.mesh)

    def __call__(self, question, model: str, context: dict):
        """An answer of the question's kind from this participant's latent judgement of the
        condition (`studyctl.synthetic.observer.logit`): yes/no with P(yes) its logistic; a rating its
        ordered-logit category; a VAS its noisy logistic; a choice the condition judged best
        with Gumbel noise (a multinomial logit over the conditions' judgements)."""
        who = self.participant
        trial = context.get("trial")
        key = f"answer:{who.seed}:{who.code}:{model}:{question.id}" + (f":{trial}" if trial is not None else "")
        rng = random.Random(key)
        if question.kind == Kind.TEXT:
            return "(synthetic participant: no comment)"
        if question.kind == Kind.CHOICE:
            feats = context["features"]
            utility = {c: logit(question, feats[c], who.traits, self.params) - math.log(-math.log(max(rng.random(), 1e-300)))
                       for c in sorted(context["labels"]) if c in feats}
            return max(utility, key=utility.get)
        if model == SESSION:  # about the whole session: the mean of its conditions' judgements
            feats = context["features"]
            eta = sum(logit(question, feats[c], who.traits, self.params) for c in sorted(feats)) / len(feats)
        else:
            if trial is not None:  # judged on that trial alone
                feats = features(self._summaries(model, context.get("results", [])), who.traits, self.params)
            else:
                feats = self.features_of(model, context.get("results", []))
            eta = logit(question, feats, who.traits, self.params)
        return judged_answer(question, eta, rng.random, lambda: rng.gauss(0.0, 1.0))
