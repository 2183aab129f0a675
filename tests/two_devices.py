"""A test script run on two emulated CPU devices: a subprocess, since XLA fixes its device count at
start-up. The script prints "RESULT" + a JSON object as its last output."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]


def run_on_two_devices(script: str) -> tuple[dict[str, Any], subprocess.CompletedProcess]:
    """(the script's RESULT object, the finished process) of `python -c script` in the repository
    root on two CPU devices; fails the test, with the output's tails, when the script fails."""
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2"}
    p = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=ROOT, env=env, timeout=900)
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    return json.loads(p.stdout.split("RESULT")[-1]), p
