#!/usr/bin/env bash
# scripts/freeze_lock.sh VENV LOCK: write VENV's installed versions (less the project itself) to
# LOCK under its header (the comment lines kept, the date and Python updated). `make lock` runs it.
set -euo pipefail
venv=$1 lock=$2
py="$venv/bin/python"
pyver=$("$py" -c 'import sys; print("%d.%d" % sys.version_info[:2])')
tmp=$(mktemp)
{
  grep '^#' "$lock" | sed -E "s/^# Made [0-9-]+ on CPython [0-9.]+, [^ ]+ [^ ]+ /# Made $(date +%F) on CPython $pyver, $(uname -s) $(uname -m) /"
  echo "pip==$("$py" -m pip --version | cut -d' ' -f2)"
  "$py" -m pip freeze --exclude-editable
} > "$tmp"
mv "$tmp" "$lock"
echo "$lock: $(grep -vc '^#' "$lock") pinned versions"
