"""vnl/train/signals: a stop request during work that holds no checkpoint yet (compiling) ends it
within a fraction of a second, from the main thread, while the work goes on in its thread."""

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from vnl.io import checkpoint
from vnl.train import signals
from vnl.train.signals import CompileInterrupted, StopRequest

ROOT = Path(__file__).resolve().parents[1]


def test_a_stop_request_cuts_interruptible_work_at_once_and_leaves_it_running():
    stop = StopRequest()
    release = threading.Event()
    with stop.installed():
        threading.Timer(0.3, lambda: os.kill(os.getpid(), signal.SIGINT)).start()
        t = time.time()
        with pytest.raises(CompileInterrupted, match="compiling the test program"):
            stop.interruptible(lambda: release.wait(60), "compiling the test program")  # like XLA: no GIL held
        assert time.time() - t < 2.0
        assert signals.abandoned()  # the work still runs: a CLI ends the process with os._exit
        release.set()
    assert stop.requested.is_set()
    # Its result and errors come back when it ends first; outside `installed` it runs in place.
    assert StopRequest().interruptible(lambda: 7, "x") == 7
    with StopRequest().installed() as s, pytest.raises(ZeroDivisionError):
        s.interruptible(lambda: 1 / 0, "dividing")
    for _ in range(50):
        if not signals.abandoned():
            break
        time.sleep(0.05)
    assert not signals.abandoned()


def _blocked_in_xla(seconds: float):
    """A compiled program that holds the calling thread in XLA for `seconds`: its host callback
    sleeps, as a training epoch holds it while MuJoCo C physics steps."""
    import jax
    import jax.numpy as jp
    import numpy as np

    def host(x):
        time.sleep(seconds)
        return np.asarray(x)

    f = jax.jit(lambda x: jax.pure_callback(host, jax.ShapeDtypeStruct((), jp.float32), x))
    return lambda: jax.block_until_ready(f(jp.float32(1.0)))


def test_a_second_ctrl_c_during_a_training_epoch_aborts_at_once():
    """While an epoch runs (the main thread would wait inside XLA, where no Python signal handler
    runs), the first SIGINT is acknowledged and lets the epoch finish; the second aborts within
    seconds, leaving the epoch to be dropped with the process."""
    stop = StopRequest()
    with stop.installed():
        for delay in (0.5, 1.0):
            threading.Timer(delay, lambda: os.kill(os.getpid(), signal.SIGINT)).start()
        t = time.time()
        with pytest.raises(KeyboardInterrupt):
            stop.responsive(_blocked_in_xla(8.0), "training")
        assert time.time() - t < 4.0  # the program holds XLA for 8 s
        assert stop.requested.is_set() and signals.abandoned()
    # The abandoned program ends on its own; no test after this one shares XLA with it.
    for _ in range(200):
        if not signals.abandoned():
            break
        time.sleep(0.05)
    assert not signals.abandoned()
    # One request alone does not cut the epoch: it runs to its end and returns its result.
    stop = StopRequest()
    with stop.installed():
        threading.Timer(0.3, lambda: os.kill(os.getpid(), signal.SIGINT)).start()
        assert float(stop.responsive(_blocked_in_xla(1.0), "training")) == 1.0
        assert stop.requested.is_set()


@pytest.mark.slow
def test_ctrl_c_while_compiling_stops_within_seconds_and_resume_starts_the_run_again(tmp_path):
    """`vnl train` stopped while it compiles exits 130 at once (not at an evaluation that is minutes
    away on a GPU), keeps its config, and `vnl train --resume` starts it from step 0."""
    run = tmp_path / "run"
    cmd = [sys.executable, "-m", "vnl", "train", "ant_run", "--preset", "tiny", "--no-video", "--out", str(run)]
    cmd += ["--set", "env_config.impl=c"]  # MuJoCo C: a compile of seconds, long enough to be cut
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=tmp_path, env=env)
    lines = []
    for line in proc.stdout:
        lines.append(line)
        if "compiling the training epoch" in line:
            break
    time.sleep(0.5)
    t = time.time()
    proc.send_signal(signal.SIGINT)
    out = "".join(lines) + proc.communicate(timeout=60)[0]
    assert proc.returncode == 130, out
    assert time.time() - t < 10, out  # seconds, on a busy 2-core machine
    assert "[vnl] stopped while compiling" in out and "starts it again from step 0" in out, out
    assert "Traceback" not in out and "terminate called" not in out, out
    assert (run / "config.yaml").is_file() and checkpoint.steps(run) == []
    again = subprocess.run(
        [sys.executable, "-m", "vnl", "train", "--resume", str(run), "--no-video"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=600,
    )
    assert again.returncode == 0, again.stdout[-2000:] + again.stderr[-2000:]
    assert "has no checkpoint yet" in again.stdout and checkpoint.steps(run)[-1] == 4096
