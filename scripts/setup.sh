#!/usr/bin/env bash
# Sets up vnl on a fresh machine: headless OpenGL (for videos) and a virtual environment .venv
# with the pinned dependency set. Safe to run again (it only installs what is missing).
set -euo pipefail
cd "$(dirname "$0")/.."

# Headless OpenGL for MuJoCo's renderer (EGL, with OSMesa as a fallback). Best effort: without it
# training works and videos are skipped with a message saying how to enable them.
if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
  if ! ldconfig -p | grep -q "libEGL.so.1" || ! ldconfig -p | grep -q "libOSMesa"; then
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
       libegl1 libgl1-mesa-dri libosmesa6 >/dev/null) \
      || echo "setup: could not install OpenGL libraries; videos will be skipped" >&2
  fi
  # Headless Chromium: the test that screenshots Rerun's web viewer with a recording loaded.
  if ! command -v chromium >/dev/null 2>&1; then
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) \
      || echo "setup: could not install chromium; the web viewer screenshot test will be skipped" >&2
  fi
else
  echo "setup: not root or no apt-get; install EGL/OSMesa yourself for videos" \
       "(Debian: libegl1 libgl1-mesa-dri libosmesa6), and chromium for the web viewer test" >&2
fi

# Python 3.12 (jax 0.11 and newer need it): $PYTHON, else python3.12, else pyenv's newest 3.12.
PY=${PYTHON:-python3.12}
if ! "$PY" -c '' >/dev/null 2>&1 && command -v pyenv >/dev/null 2>&1; then
  v=$(pyenv versions --bare 2>/dev/null | grep -E '^3\.12\.[0-9]+$' | sort -V | tail -1 || true)
  if [ -n "$v" ]; then PY="$(pyenv root)/versions/$v/bin/python3.12"; fi
fi
"$PY" -c '' >/dev/null 2>&1 || PY=python3
"$PY" -c 'import sys; assert sys.version_info[:2] == (3, 12), f"vnl needs Python 3.12, found {sys.version.split()[0]}"'
# A .venv of another Python (an earlier vnl's 3.11) is made anew.
if [ -x .venv/bin/python ] && ! .venv/bin/python -c 'import sys; assert sys.version_info[:2] == (3, 12)' 2>/dev/null; then
  rm -rf .venv
fi
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
# requirements.lock pins every transitive dependency to the set tested in CI.
.venv/bin/python -m pip install -q -c requirements.lock -e ".[dev]"
echo "setup: done (.venv ready; try .venv/bin/vnl list)"
