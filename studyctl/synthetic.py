"""Synthetic participants: a motor model and an answer model, both driven by the simulator.

A synthetic participant is a model, not data, and everything it produces is labelled
synthetic. See docs/synthetic.md for the model and its parameters.

- Motor model: for each trial and hand, a minimum-jerk pull along the surface (the scene's
  scripted pull, scaled per participant in distance and duration), physiological tremor
  (8-12 Hz, 0.1-0.4 mm per axis), and the participant's own hand impedance, which the
  rendered force acts on.
- Answer model: P(yes) for a question after a condition is a logistic function of what the
  simulator measured for this participant's trials of that condition: deformation latency,
  the fraction of force samples within the JND of the FEM reference on the same hand motion,
  force jitter, and safety events, plus a per-participant bias. No outcome is set per model.
"""

from __future__ import annotations

import dataclasses
import math
import random
from dataclasses import dataclass

import numpy as np

from sim.calibrate import jnd

# question -> weights on (latency, accuracy, smoothness, stability); a base logit of 1.0 is
# about 73% yes, near the paper's overall rate
WEIGHTS = {
    "natural": (0.3, 1.2, 0.5, 0.3),
    "behaviour": (0.3, 1.0, 0.5, 0.3),
    "texture": (0.0, 1.5, 0.3, 0.0),
    "comfortable": (0.3, 0.3, 1.0, 0.5),
    "guidance": (0.3, 1.0, 0.3, 0.3),
    "realtime": (1.5, 0.0, 0.3, 0.3),
    "feedback": (0.0, 1.5, 0.5, 0.3),
    "deformation": (0.5, 1.0, 0.3, 0.0),
    "stable": (0.3, 0.0, 1.0, 1.5),
}
DEFAULT_WEIGHTS = (0.5, 0.8, 0.5, 0.5)
BASE_LOGIT = 1.0
MAX_SYNTHETIC = 1000  # participants per `synth` call: a study, not a stress test (the paper had 35)
# Deformation latency enters as a perceived category, from the literature's thresholds: haptic
# task performance degrades from about 25 ms, visual-haptic asynchrony is detected from about
# 45 ms. Categories (0, 1, 2) also keep answers independent of small timing noise, so the same
# seed gives the same answers on the same machine.
LATENCY_THRESHOLDS_MS = (25.0, 45.0)
SAFETY_EVENTS = ("force_clamped", "nan_force", "model_unstable", "deadline_streak", "device_fault", "position_jump", "nan_position")


@dataclass(frozen=True)
class SyntheticParticipant:
    code: str
    seed: int
    pull_scale: float  # times the scene's pull distance
    time_scale: float  # times the scene's pull duration
    tremor_m: float
    tremor_hz: float
    stiffness: float  # hand stiffness, N/m
    bias: float  # logit offset: some people say yes more

    @classmethod
    def draw(cls, code: str, seed: int) -> SyntheticParticipant:
        rng = random.Random(f"participant:{seed}:{code}")
        return cls(
            code=code, seed=seed,
            pull_scale=rng.uniform(0.8, 1.2), time_scale=rng.uniform(0.8, 1.3),
            tremor_m=rng.uniform(0.1e-3, 0.4e-3), tremor_hz=rng.uniform(8.0, 12.0),
            stiffness=rng.uniform(200.0, 500.0), bias=rng.gauss(0.0, 0.6),
        )

    def operators(self, scene, trial: int, model: str) -> list:
        """This participant's pulls for one trial: the scene's, varied per trial and hand."""
        from sim.devices.simulated import HandImpedance

        rng = random.Random(f"trial:{self.seed}:{self.code}:{model}:{trial}")
        out = []
        for i in range(len(scene.spec.hands)):
            base = scene.spec.hands[i].script(scene.mesh)
            s = self.pull_scale * rng.uniform(0.9, 1.1)
            mass = 0.2
            damping = 2 * 0.7 * math.sqrt(self.stiffness * mass)
            out.append(dataclasses.replace(
                base,
                pull=tuple(s * c for c in base.pull),
                pull_time=base.pull_time * self.time_scale * rng.uniform(0.9, 1.1),
                tremor_m=self.tremor_m, tremor_hz=self.tremor_hz,
                tremor_phase=tuple(rng.uniform(0, 2 * math.pi) for _ in range(3)),
                impedance=HandImpedance(mass_kg=mass, stiffness_n_per_m=self.stiffness, damping_ns_per_m=damping),
            ))
        return out


def reference_forces(result, reference, mesh) -> np.ndarray:
    """The FEM reference's force magnitude for the same hand motion and grasps, per tick and hand."""
    out = np.zeros(result.positions.shape[:2])
    grasps = {}
    for e in result.events:
        if e.kind == "grasp":
            grasps.setdefault(e.hand, []).append((e.t, int(e.detail.split()[1])))
    for hand, items in grasps.items():
        for k, (t0, vertex) in enumerate(items):
            t1 = items[k + 1][0] if k + 1 < len(items) else math.inf
            sel = (result.times >= t0) & (result.times < t1) & result.buttons[:, hand]
            if not sel.any():
                continue
            contact = reference.grasp(mesh.vertices[vertex], hand)
            K = np.asarray(contact.law.K).reshape(3, 3)
            d = result.positions[sel, hand] - np.asarray(contact.point)
            out[sel, hand] = np.linalg.norm(d @ K.T, axis=1)
    return out


def features(results: list, reference, mesh) -> dict:
    """What a participant felt in one condition, from its trials' runs."""
    lat, within, jitter, events = [], [], [], 0
    for r in results:
        if len(r.deformation_s):
            lat.append(float(np.mean(r.deformation_s)) * 1e3)
        f = np.linalg.norm(r.forces, axis=2)
        ref = reference_forces(r, reference, mesh) if reference is not None else f
        mask = (ref > 0.01) & (f > 0)
        if mask.any():
            within.append(float(np.mean(np.abs(f[mask] - ref[mask]) <= jnd(ref[mask]) * ref[mask])))
        for i in range(f.shape[1]):
            fi = f[:, i][f[:, i] > 0.01]
            if len(fi) > 10:
                jitter.append(float(np.std(np.diff(fi, 2)) / max(np.mean(fi), 1e-3)))
        events += sum(1 for e in r.events if e.kind in SAFETY_EVENTS)
    return {
        "latency_ms": float(np.mean(lat)) if lat else 0.0,
        "within_jnd": float(np.mean(within)) if within else 1.0,
        "jitter": float(np.mean(jitter)) if jitter else 0.0,
        "events": events / max(len(results), 1),
    }


def latency_category(ms: float) -> int:
    return sum(ms >= t for t in LATENCY_THRESHOLDS_MS)


def p_yes(item: str, feats: dict, bias: float = 0.0) -> float:
    w_lat, w_acc, w_smooth, w_stab = WEIGHTS.get(item, DEFAULT_WEIGHTS)
    z = (
        BASE_LOGIT + bias
        - w_lat * latency_category(feats["latency_ms"])
        + w_acc * 2.0 * (feats["within_jnd"] - 0.5)
        - w_smooth * min(feats["jitter"] / 0.01, 3.0)
        - w_stab * min(feats["events"], 3.0)
    )
    return 1.0 / (1.0 + math.exp(-z))


class SyntheticAnswers:
    """Answers from the answer model, drawn with a seeded generator (labelled synthetic)."""

    source = "synthetic"

    def __init__(self, participant: SyntheticParticipant, reference=None, mesh=None):
        self.participant = participant
        self.reference, self.mesh = reference, mesh
        self._feats: dict[str, dict] = {}

    def begin(self, label: str) -> None:
        pass

    def __call__(self, question, model: str, measured: dict) -> bool:
        if model not in self._feats:
            self._feats[model] = features(measured.get("results", []), self.reference, self.mesh)
        p = p_yes(question.id, self._feats[model], self.participant.bias)
        rng = random.Random(f"answer:{self.participant.seed}:{self.participant.code}:{model}:{question.id}")
        return rng.random() < p


def run_synthetic_study(db, participants: int, seed: int = 0, jobs: int = 1, protocol_path=None, progress=None) -> dict:
    """Register N synthetic participants, give them counterbalanced orders, run their sessions.

    Codes, ages, orders and session ids are assigned up front and in order, so orders, trials
    and forces are the same for the same seed whatever `jobs` is, and so are the answers where
    the measured latency falls in the same category (measured times are wall-clock)."""
    import time as _time
    from pathlib import Path

    from studyctl.errors import InputError
    from studyctl.protocol import load_protocol
    from studyctl.store import Store, init_study, now
    from studyctl.study import assign_order

    if not 1 <= participants <= MAX_SYNTHETIC:
        raise InputError(f"--participants: {participants} is out of range; allowed: 1..{MAX_SYNTHETIC}")
    if not 1 <= jobs <= 64:
        raise InputError(f"--jobs: {jobs} is out of range; allowed: 1..64")
    if not Path(db).exists():
        if protocol_path is None:
            from studyctl.errors import StoreError

            raise StoreError(f"{db}: no such study database; give --protocol to create it")
        init_study(db, protocol_path)
    store = Store(db)
    try:
        protocol = store.protocol()
        rng = random.Random(f"ages:{seed}")
        if protocol_path is not None and load_protocol(protocol_path).sha256 != protocol.sha256:
            raise InputError(f"--protocol: {protocol_path} is not the protocol {db} was created with; leave --protocol out")
        first_id = (store.rows("select max(id) as m from sessions")[0]["m"] or 0) + 1
        registered = {r["code"] for r in store.rows("select code from participants")}
        codes, k = [], 0
        while len(codes) < participants:  # S001, S002, ... skipping codes already in use
            k += 1
            if f"S{k:03d}" not in registered:
                codes.append(f"S{k:03d}")
        with store.transaction() as conn:  # all registered or none
            for code in codes:
                conn.execute("insert into participants (code, age, synthetic, created_at) values (?, ?, 1, ?)",
                             (code, rng.randint(protocol.age_min, protocol.age_max), now()))
                assign_order(store, protocol, code)
    finally:
        store.close()
    tasks = [(str(db), code, seed, first_id + k) for k, code in enumerate(codes)]
    t0 = _time.perf_counter()
    if jobs == 1:
        for k, task in enumerate(tasks):
            _run_one(task)
            if progress:
                progress(k + 1, len(tasks))
    else:
        import multiprocessing as mp

        with mp.get_context("spawn").Pool(jobs) as pool:
            for k, _ in enumerate(pool.imap_unordered(_run_one, tasks)):
                if progress:
                    progress(k + 1, len(tasks))
    return {"participants": len(codes), "codes": codes, "seed": seed, "jobs": jobs, "seconds": _time.perf_counter() - t0}


def _run_one(task) -> str:
    from studyctl.session import run_session

    db, code, seed, session_id = task
    run_session(db, code, synthetic=True, seed=seed, time_scale=0.0, session_id=session_id)
    return code
