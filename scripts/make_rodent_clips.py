"""Makes vnl/tasks/data/rodent_clips.h5, the clips `rodent_imitate` tracks by default: stretches of
vnl's own rat running, from a recording of a trained `rodent_run` policy.

    .venv/bin/python scripts/make_rodent_clips.py RECORDING.nc [--out vnl/tasks/data/rodent_clips.h5]

The shipped file was made on 2026-11-27 from `~/vnl-runs/rodent_run-s0/trained.nc`: `vnl train
rodent_run --preset cpu --seed 0` (5.1M steps, 1.58 m/s at its last evaluation), recorded with
`vnl record` (6 episodes of 500 control steps of 20 ms, deterministic policy); its qpos per
control step. Each clip is `CLIP_FRAMES` frames (2 s at 50 fps) of one episode that ran its full
length, starting at `STARTS`: the start from standstill and two stretches of the running gait.
Bodies and velocities come from the qpos by MuJoCo's kinematics on the rat's world
(`vnl.mocap.clips.clip_from_qpos`), so they are the rat's exactly.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

CLIP_FRAMES = 100
STARTS = ((3, 0), (4, 150), (5, 300))  # (episode, first frame) of each clip
OUT = Path(__file__).resolve().parents[1] / "vnl" / "tasks" / "data" / "rodent_clips.h5"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", type=Path, help="a vnl record NetCDF file of a rodent_run policy")
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args()

    import h5py

    from vnl.arenas import floor
    from vnl.mocap.clips import clip_from_qpos, save_clips
    from vnl.tasks.base import build_walker, compile_world
    from vnl.tasks.imitate import RODENT_IMITATE

    with h5py.File(args.recording, "r") as f:
        qpos, active = np.asarray(f["qpos"]), np.asarray(f["active"])
        fps = 1.0 / float(np.ravel(f.attrs["control_dt"])[0])
        env = str(f.attrs["env"])
    model, _ = compile_world(build_walker(RODENT_IMITATE), floor.build(RODENT_IMITATE.floor_size))
    if qpos.shape[-1] != model.nq:
        raise SystemExit(f"{args.recording}: qpos has {qpos.shape[-1]} columns, the rat's world {model.nq}")
    clips = []
    for episode, start in STARTS:
        stop = start + CLIP_FRAMES
        if active[episode, :stop].min() < 1:
            raise SystemExit(f"{args.recording}: episode {episode} ended before frame {stop}")
        source = f"{args.recording.name} ({env}), episode {episode}, frames {start}-{stop - 1}"
        clips.append(clip_from_qpos(f"run_{episode}_{start}", model, qpos[episode, start:stop], fps, "rodent", source))
    save_clips(args.out, clips)
    print(f"wrote {args.out}: {len(clips)} clips of {CLIP_FRAMES} frames at {fps:g} fps")


if __name__ == "__main__":
    main()
