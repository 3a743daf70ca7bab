#!/usr/bin/env bash
# Everything made from the shipped truth (data/reference_pulls.npz), made again after the truth is
# re-solved (scripts/make_reference_pulls.py; docs/reference.md, "Making the truth again"):
#   the observer's truth, the located plate-spring's field and curve, the scene-fit plate-spring,
#   the rig profile of the shipped protocols (their scene file is part of every condition's key),
# then, into OUT (default /tmp/downstream), what the docs quote: the fair bench's JSON, the paper
# study's synthetic answers (35 participants, seed 1) with their decided share, and its Table 1.
# Run from the repository root with the venv made (make venv); on a quiet machine (the rig profile
# and the bench's frame times are timings). Each step's output and errors are kept in OUT.
set -euo pipefail
OUT=${1:-/tmp/downstream}
STUDYCTL=${STUDYCTL:-.venv/bin/studyctl}
PYTHON=${PYTHON:-.venv/bin/python}
mkdir -p "$OUT"
step() {  # name, command...: run it, its stdout and stderr into OUT, stop on failure
    local name=$1; shift
    echo "$(date -u +%H:%M:%S) $name" >&2
    "$@" > "$OUT/$name.out" 2> "$OUT/$name.err" || { echo "$name failed (exit $?): $OUT/$name.err" >&2; exit 1; }
}
# the observer's truth beside the plate-spring's fits; the located curve's fit starts from the
# scene's plate-spring parameters, so the scene-fit is made first
step truth "$STUDYCTL" calibrate truth --out data/observer_truth.npz --force --json &
t=$!
step plate_spring "$STUDYCTL" calibrate plate-spring --out protocols/models/plate_spring_brain.toml --force --json
step field "$STUDYCTL" calibrate field --params-out protocols/models/plate_spring_located.toml --force --json
wait $t
for protocol in brain_pull_2015 plate_spring_variants; do
    step "rig_$protocol" "$STUDYCTL" calibrate rig --protocol "protocols/$protocol.toml" --trials 3 --out "$OUT/rig_$protocol.json" --force --json
done
"$PYTHON" - "$OUT" <<'PY'
import json, sys
from pathlib import Path
out = Path(sys.argv[1])
shipped = json.loads(Path("data/rig_ci.json").read_text())
parts = [json.loads((out / f"rig_{p}.json").read_text()) for p in shipped["protocols"]]
keep = {k: v for k, v in shipped.items() if k not in ("conditions", "machine", "measured_at", "software_version")}
merged = keep | {k: parts[0][k] for k in ("machine", "measured_at", "software_version")} | {"conditions": [r for p in parts for r in p["conditions"]]}
Path("data/rig_ci.json").write_text(json.dumps(merged, indent=2) + "\n")
PY
step accuracy "$STUDYCTL" bench accuracy --json --out "$OUT/accuracy" --force
rm -f "$OUT/t1.db"
step synth "$STUDYCTL" synth --db "$OUT/t1.db" --protocol protocols/brain_pull_2015.toml --participants 35 --seed 1 --jobs 2
step decided_share "$PYTHON" scripts/decided_share.py --db "$OUT/t1.db" --json
step table1 "$STUDYCTL" report table1 --db "$OUT/t1.db"
echo "done: $OUT" >&2
