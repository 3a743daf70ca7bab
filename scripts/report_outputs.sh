#!/bin/bash
# Every report of a set of study databases, each command's output, error text and exit code in
# its own file, so that two checkouts' outputs can be compared byte for byte (`diff -r`):
#
#   bash scripts/report_outputs.sh DBDIR OUTDIR [PYTHON]
#
# DBDIR holds study databases (*.db; read-only copies keep them unchanged); PYTHON runs the
# checkout's studyctl (default: this checkout's .venv/bin/python, with PYTHONPATH set to the
# checkout, so a second worktree can use the same venv). Per database: report text (md, latex,
# json, APA), report stats (plain, json, Holm within each question), report table1 (md, csv, latex,
# html, json), report jnd and report validity (md, html, json, latex), metrics (csv, json),
# status (plain, json); and report published (plain, json) once. A command that refuses a
# study (report jnd of a study without discrimination trials) is an output too: its message
# and exit code.
set -u
here=$(cd "$(dirname "$0")/.." && pwd)
dbs=$(cd "$1" && pwd)
mkdir -p "$2" && out=$(cd "$2" && pwd)
py=${3:-$here/.venv/bin/python}
export COLUMNS=120 NO_COLOR=1 PYTHONPATH=$here
cd "$out"
run() {  # NAME ARGS...: stdout in NAME, stderr in NAME.err, exit code in NAME.rc
    local name=$1; shift
    "$py" -m studyctl "$@" > "$name" 2> "$name.err"
    echo $? > "$name.rc"
}
for db in "$dbs"/*.db; do
    s=$(basename "$db" .db)
    run "$s.text.md" report text --db "$db"
    run "$s.text.tex" report text --db "$db" --format latex
    run "$s.text.json" report text --db "$db" --format json
    run "$s.text.apa.md" report text --db "$db" --style apa
    run "$s.stats.txt" report stats --db "$db"
    run "$s.stats.json" report stats --db "$db" --json
    run "$s.stats.question.json" report stats --db "$db" --json --holm question
    for f in md csv latex html json; do run "$s.table1.$f" report table1 --db "$db" --format $f; done
    for f in md html json latex; do
        run "$s.jnd.$f" report jnd --db "$db" --format $f
        run "$s.validity.$f" report validity --db "$db" --format $f
    done
    run "$s.metrics.csv" metrics --db "$db" --format csv
    run "$s.metrics.json" metrics --db "$db" --format json
    run "$s.status.txt" status --db "$db"
    run "$s.status.json" status --db "$db" --json
done
run published.txt report published
run published.json report published --json
# the checkout's own path is not an output change
sed -i "s|$here|CHECKOUT|g" "$out"/*
echo "$(ls "$out" | grep -vc '\.\(err\|rc\)$') outputs in $out"
