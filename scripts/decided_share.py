"""The paper study's synthetic participants judged on decided evidence: how much of the judged
time is on decided truth, per hand, and the yes counts per model under the observer's former
rule (a sample where the truth is not decided judged against its band) and its rule now (such
a sample carries no accuracy judgement), from one synthetic run: the same seed, the same traces.

    python scripts/decided_share.py [--participants 35] [--seed 1] [--jobs 1] [--db STUDY.db] [--json]

Runs `studyctl synth` of protocols/brain_pull_2015.toml into a temporary folder (or reads the
synthetic study `--db` names, made by `synth`), then judges every stored trace again with both
rules (`studyctl.synthetic.participant.SyntheticAnswers`, the answers' own seeded draws). The
rule now must give the answers `synth` stored (checked: the script stops otherwise), so the two
columns differ by the rule alone. The truth is the installed one (data/observer_truth.npz): its
SHA-256 and where each hand's path stops being decided are printed with the numbers, so a rerun
after the truth is rebuilt says which truth it judged against.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

import numpy as np

from analysis.study.questions import NOT_PER_TRIAL, Kind
from analysis.verification.truth import TRUTH_FILE, load_truth
from studyctl.conditions import scene_itself
from studyctl.session.traces import trial_traces
from studyctl.store import Store
from studyctl.store.sessions import condition_labels, participant_sessions
from studyctl.store.snapshot import answers
from studyctl.synthetic.observer import DEFAULT, judged_time
from studyctl.synthetic.participant import SyntheticAnswers, SyntheticParticipant, skill_for
from studyctl.synthetic.rig import frame_times
from studyctl.synthetic.synth_run import run_synthetic_study

ROOT = Path(__file__).resolve().parents[1]
PROTOCOL = ROOT / "protocols/brain_pull_2015.toml"
RULES = {"before": dataclasses.replace(DEFAULT, judge_undecided=True), "after": DEFAULT}


def decided_extent(truth) -> dict[str, float]:
    """Per path (by its own vertex), the last record up to which every record is decided, mm."""
    out = {}
    for h, v in enumerate(truth.path_vertex):
        rec = np.asarray(truth.path_decided[h], dtype=bool)
        k = int(np.argmin(rec)) if not rec.all() else len(rec)
        out[f"vertex {int(v)}"] = float(truth.s[k - 1] * 1e3) if k else 0.0
    return out


def judge(db: Path) -> dict:
    """Both rules' yes counts and the decided share of judged time, from the study's traces."""
    with Store(db, mode="read") as store:
        protocol = store.protocol()
        base = scene_itself(protocol)
        truth = load_truth(base)
        rig = {c: v["frame_ms"] for c, v in frame_times(protocol, store).items()}
        stored = answers(store)
        questions = [q for q in protocol.asked("condition") if q.kind == Kind.YES_NO]
        kept = {(r.code, r.model, r.item): bool(int(r.answer)) for r in stored.itertuples() if int(r.trial) == NOT_PER_TRIAL}
        yes = {rule: defaultdict(lambda: defaultdict(int)) for rule in RULES}
        within = {rule: defaultdict(list) for rule in RULES}  # each participant's within_jnd of each model (NaN: nothing judged)
        counts = defaultdict(lambda: np.zeros(2, dtype=np.int64))  # (hand, model) -> judged, decided samples
        differ, n = [], defaultdict(int)
        for code in sorted(set(stored["code"])):
            for sess in participant_sessions(store, code):
                if not sess["synthetic"]:
                    continue
                who = SyntheticParticipant.draw(code, int(sess["seed"]), skill_for(store, protocol, code))
                labels = {r["model"]: r["label"] for r in condition_labels(store, sess["id"])}
                for model in sorted(labels):
                    results = trial_traces(store, sess["id"], model)
                    for tr in results:
                        for name, c in zip(tr.hand_names, judged_time(tr, truth, base.mesh)):
                            counts[(name, model)] += c
                    n[model] += 1
                    for rule, params in RULES.items():
                        answerer = SyntheticAnswers(who, truth, base.mesh, params, rig)
                        within[rule][model].append(answerer.features_of(model, results)["within_jnd"])
                        for q in questions:
                            a = bool(answerer(q, model, {"labels": labels, "trial": None, "results": results}))
                            yes[rule][model][q.id] += a
                            if rule == "after" and kept.get((code, model, q.id)) != a:
                                differ.append(f"{code} {model} {q.id}")
    if differ:
        raise SystemExit(f"{db}: the observer's rule now does not give the stored answers ({len(differ)}, first {differ[0]}); "
                         "was the study made by another version?")
    hands = sorted({h for h, _ in counts})
    models = sorted(n)
    share = {h: {m: _share(counts[(h, m)]) for m in models} | {"all": _share(sum(counts[(h, m)] for m in models))} for h in hands}
    return {"db": str(db), "truth": str(TRUTH_FILE), "truth_sha256": hashlib.sha256(TRUTH_FILE.read_bytes()).hexdigest(),
            "decided_to_mm": decided_extent(truth), "participants": {m: n[m] for m in models},
            "questions": [q.id for q in questions], "decided_share": share,
            "yes": {rule: {m: {"total": sum(yes[rule][m].values()), "of": n[m] * len(questions)} | dict(yes[rule][m]) for m in models}
                    for rule in RULES},
            "within_jnd": {rule: {m: {"mean": float(np.nanmean(within[rule][m])) if np.isfinite(within[rule][m]).any() else float("nan"),
                                      "nothing_judged": int(np.isnan(within[rule][m]).sum())} for m in models} for rule in RULES}}


def _share(c) -> dict:
    judged, decided = (int(x) for x in c)
    return {"judged": judged, "decided": decided, "share": decided / judged if judged else float("nan")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--participants", type=int, default=35)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--db", type=Path, help="a synthetic study of the paper's protocol already made (nothing is run)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        db = args.db
        if db is None:
            db = Path(d) / "study.db"
            run_synthetic_study(db, args.participants, seed=args.seed, jobs=args.jobs, protocol_path=PROTOCOL)
        out = judge(db) | {"seed": args.seed if args.db is None else None}
    if args.json:
        print(json.dumps(out, indent=1))
        return
    print(f"truth {out['truth']} (SHA-256 {out['truth_sha256'][:12]}...), decided along the paths up to "
          + ", ".join(f"{v:g} mm ({k})" for k, v in out["decided_to_mm"].items()))
    for h, by in out["decided_share"].items():
        print(f"{h}: {by['all']['decided']} of {by['all']['judged']} judged samples on decided truth ({by['all']['share']:.1%}); "
              + ", ".join(f"{m} {v['share']:.1%}" for m, v in by.items() if m != "all"))
    for rule, by in out["yes"].items():
        print(f"{rule}: yes " + ", ".join(f"{m} {v['total']} of {v['of']}" for m, v in by.items()) + "; mean within_jnd "
              + ", ".join(f"{m} {v['mean']:.3f}" + (f" ({v['nothing_judged']} judged nothing)" if v["nothing_judged"] else "")
                          for m, v in out["within_jnd"][rule].items()))


if __name__ == "__main__":
    sys.exit(main())
