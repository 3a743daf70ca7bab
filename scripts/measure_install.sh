#!/usr/bin/env bash
# Install size and time of a new venv from a wheel, no pip cache (docs/install.md):
#   scripts/measure_install.sh dist/brainsim_study-*.whl [python3.11]
set -euo pipefail
wheel=$1
py=${2:-python3.11}
d=$(mktemp -d)/venv
"$py" -m venv "$d"
"$d/bin/python" -m pip install -q --upgrade "pip>=25.1"
start=$(date +%s.%N)
"$d/bin/python" -m pip install -q --no-cache-dir "$wheel"
end=$(date +%s.%N)
site=$("$d/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
echo "install_s $(echo "$end - $start" | bc) venv $(du -sh "$d" | cut -f1) open3d $(du -sh "$site/open3d" | cut -f1)"
rm -rf "$(dirname "$d")"
