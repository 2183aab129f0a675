#!/usr/bin/env bash
# vnl without a checkout: builds vnl's wheel, installs it into a fresh virtual environment (its
# dependencies pinned by requirements.lock, from PyPI or pip's cache), and, from an empty directory
# outside the checkout, checks the install holds every file of the package (`git ls-files vnl`) and
# resolves a tiny run's config as the checkout does, then runs what a new user runs first: `vnl list`,
# a tiny training run and `vnl eval` of it. Exits non-zero on the first failure.
#
#   bash scripts/wheel_check.sh [OUT_DIR]     # OUT_DIR keeps the wheel (default: a temporary directory)
set -euo pipefail
cd "$(dirname "$0")/.."
START=$SECONDS
step() { echo "wheel_check: $1 ($((SECONDS - START)) s)"; }
ROOT=$PWD
PY=${PYTHON:-.venv/bin/python}
case $PY in /*) ;; *) PY="$ROOT/$PY" ;; esac
WORK=$(mktemp -d -t vnl-wheel-XXXXXX)
trap 'rm -rf "$WORK"' EXIT
DIST=${1:-$WORK/dist}
mkdir -p "$DIST"

# The wheel, from this checkout (setuptools from the dev environment: no download).
rm -f "$DIST"/vnl-*.whl
"$PY" -m pip wheel -q --no-deps --no-build-isolation -w "$DIST" "$ROOT"
WHEEL=$(ls "$DIST"/vnl-*.whl)
step "built $(basename "$WHEEL")"

# What the checkout says an install must hold: every file of the vnl package (its presets too), and
# the config a tiny run resolves to (a preset file missing from the wheel would change it silently).
git -C "$ROOT" ls-files vnl | grep -v '/__pycache__/' | sort > "$WORK/expected_files"
(cd "$WORK" && PYTHONPATH="$ROOT" "$PY" -m vnl train ant_run --preset tiny --print-config) > "$WORK/expected_config"

# A fresh venv of the same Python (not the dev one's packages), vnl from the wheel alone.
BASE=$("$PY" -c 'import sys; print(sys._base_executable)')
"$BASE" -m venv "$WORK/venv"
"$WORK/venv/bin/python" -m pip install -q --disable-pip-version-check -c "$ROOT/requirements.lock" "$WHEEL"
step "installed it into a fresh venv"

# From an empty directory: nothing of the checkout on the path.
mkdir -p "$WORK/user" && cd "$WORK/user"
unset PYTHONPATH
export VNL_COMPILE_CACHE="$WORK/jax-cache"
EXPECTED="$WORK/expected_files" "$WORK/venv/bin/python" - <<'EOF'
import os, pathlib
import vnl
where = pathlib.Path(vnl.__file__).resolve().parent
assert "site-packages" in where.parts, f"vnl imported from {where}, not from the installed wheel"
installed = {f"vnl/{p.relative_to(where).as_posix()}" for p in where.rglob("*") if "__pycache__" not in p.parts}
missing = sorted(set(pathlib.Path(os.environ["EXPECTED"]).read_text().split()) - installed)
assert not missing, f"the wheel lacks {len(missing)} file(s) of the package: {missing[:10]}"
assert "ant_run" in vnl.names(), vnl.names()
print(f"wheel_check: import vnl from site-packages: every file of the package, {len(vnl.names())} envs")
EOF
"$WORK/venv/bin/vnl" train ant_run --preset tiny --print-config > "$WORK/installed_config"
diff "$WORK/expected_config" "$WORK/installed_config" || { echo "wheel_check: the installed vnl resolves another config" >&2; exit 1; }
"$WORK/venv/bin/vnl" list >/dev/null
"$WORK/venv/bin/vnl" train ant_run --preset tiny --set env_config.impl=c --no-video --out runs/smoke
"$WORK/venv/bin/vnl" eval runs/smoke --episodes 2 --steps 50
test -s runs/smoke/metrics.jsonl && test -s runs/smoke/eval.json
step "ok: $(basename "$WHEEL") installs into a fresh venv; list, train and eval ran from an empty directory"
