"""What a checkpoint must keep of the training envs' physics state (issue 57), and its size.

`--reads`: for each env (MJX or MuJoCo C physics, `--impl`), which derived fields of the physics
state one training step reads. The env is wrapped as training wraps it (`wrap_for_training`:
vmap, episode limit, auto-reset), stepped 8 times with random actions (so that feet touch the
floor), then stepped once more with one field replaced by garbage (NaN, and four finite kinds:
1.5x + 0.25, x - 1000, x + 1000, -x - 1; integers move, booleans flip) and compared bit for bit
with the unchanged step. Each field is tried on a normal step and on one that blows up (an
infinite applied force: the physics returns the previous state, from which the task computes
that step's reward, metrics and done). A field is read when a finite garbage changes an output
that training uses (observation, reward, done, metrics, info) or a kept physics field; the kept
set grows until nothing outside it is read (a fixed point), and is compared with the task's
`previous_state_reads`.

`--joint`: every field a checkpoint leaves out is garbage at once, in the current and the first
(auto-reset) state, for 3 steps through an episode's end (from a normal and a blown-up step);
no output but those fields may change.

`--recompute`: whether the derived fields could instead be recomputed at load: `mjx_physics.sync`
and `mjx.forward`, each jitted on its own, on a saved state's integration state, compared bit for
bit with the saved values.

`--compressed`: the bytes per env of a checkpoint's (compact) env arrays after 50 random steps of
64 envs, written plain (`np.savez`) and compressed (`np.savez_compressed`, what checkpoints use).

`--sizes`: a checkpoint's bytes for the `gpu` and `cpu` presets of rodent_run, humanoid_run and
ant_run, with all of the env states (as before issue 57) and compact, from shapes only
(`jax.eval_shape`, nothing compiled).

    .venv/bin/python benchmarks/checkpoint_state.py --reads ant_run rodent_run --out reads.json
    .venv/bin/python benchmarks/checkpoint_state.py --reads --impl c      # every env, MuJoCo C
    .venv/bin/python benchmarks/checkpoint_state.py --joint ant_run ant_run_gaps
    .venv/bin/python benchmarks/checkpoint_state.py --recompute rodent_run
    .venv/bin/python benchmarks/checkpoint_state.py --sizes
    .venv/bin/python benchmarks/checkpoint_state.py --compressed rodent_run humanoid_run ant_run
"""

from __future__ import annotations

import argparse
import datetime
import json
import sys
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jp
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vnl import physics  # noqa: E402
from vnl.envs import registry  # noqa: E402
from vnl.envs.wrappers import wrap_for_training  # noqa: E402
from vnl.physics import mjx_physics  # noqa: E402
from vnl.physics.c_physics import STATE  # noqa: E402

BATCH = 2
WARMUP = 8


def _paths(tree: Any) -> dict[str, Any]:
    return {jax.tree_util.keystr(p): x for p, x in jax.tree_util.tree_flatten_with_path(tree)[0]}


FINITE = (1, 2, 3, 4)


def _garbage(x: np.ndarray, kind: int) -> np.ndarray | None:
    """`x` made wrong everywhere: NaN (kind 0), or finite: 1.5 x + 0.25, x - 1000, x + 1000, -x - 1
    (kinds 1-4: across any threshold, either sign); integers move by 1 or -2, booleans flip. None
    where a kind does not apply."""
    if x.dtype == np.bool_:
        return ~x if kind == 1 else None
    if np.issubdtype(x.dtype, np.integer):
        return {1: x + 1, 2: x - 2}.get(kind)
    changes = {0: lambda: np.full_like(x, np.nan), 1: lambda: x * 1.5 + 0.25, 2: lambda: x - 1000}
    changes |= {3: lambda: x + 1000, 4: lambda: -x - 1}
    return changes[kind]().astype(x.dtype)


def _replace(state: Any, path: str, value: np.ndarray) -> Any:
    leaves, treedef = jax.tree_util.tree_flatten_with_path(state)
    new = [value if jax.tree_util.keystr(p) == path else x for p, x in leaves]
    return jax.tree_util.tree_unflatten(treedef, new)


def _changed(a: dict[str, Any], b: dict[str, Any]) -> list[str]:
    return [k for k in a if np.asarray(a[k]).tobytes() != np.asarray(b[k]).tobytes()]


def _setup(name: str, impl: str, vision: bool, overrides: dict[str, Any]) -> tuple[Any, Any, Any, Any, Any]:
    """(env, wrapped env, jitted step, a state after `WARMUP` random steps, the test step's action)."""
    env = registry.make(name, vision=vision, impl=impl, **overrides)
    wrapped = wrap_for_training(env, episode_length=1000)
    step = jax.jit(wrapped.step)
    state = jax.jit(wrapped.reset)(jax.random.split(jax.random.PRNGKey(0), BATCH))
    key = jax.random.PRNGKey(1)
    for _ in range(WARMUP):
        key, k = jax.random.split(key)
        state = step(state, jax.random.uniform(k, (BATCH, env.action_size), minval=-1, maxval=1))
    action = jax.random.uniform(key, (BATCH, env.action_size), minval=-1, maxval=1)
    return env, wrapped, step, jax.device_get(state), action


def _blow_up(state: Any) -> Any:
    data = state.data.replace(qfrc_applied=np.full_like(state.data.qfrc_applied, np.inf))
    return state.replace(data=data)


def _field(path: str) -> str:
    """The name a task reads a leaf by (`data.<name>`): `.xpos` -> xpos, `._impl.contact.dist` -> contact."""
    return path.removeprefix(".").removeprefix("_impl.").split(".")[0]


def _candidates(state: Any, impl: str) -> list[str]:
    """The paths (`.data.<leaf>`) of the physics fields that are not integration state."""
    fields = [p for p in _paths(state.data) if _field(p) not in (mjx_physics.INTEGRATION if impl != "c" else STATE)]
    return [".data" + p for p in fields]


def reads(name: str, impl: str, vision: bool = False, overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """Per mode (normal, blow_up): for each non-integration field, the outputs its garbage changed
    (`finite`: kinds 1-4; `nan`: kind 0)."""
    t = time.time()
    env, _, step, state, action = _setup(name, impl, vision, overrides or {})
    result: dict[str, Any] = {"env": name, "impl": impl, "vision": vision, "set": overrides or {}, "modes": {}}
    for mode, s in (("normal", state), ("blow_up", _blow_up(state))):
        base = _paths(jax.device_get(step(s, action)))
        if mode == "blow_up":
            assert float(np.asarray(base[".metrics['physics_nan']"]).min()) == 1.0, "the step did not blow up"
        fields = {}
        for path in _candidates(s, impl):
            x = np.asarray(_paths(s)[path])
            if x.size == 0:
                continue
            changed: dict[str, set[str]] = {"finite": set(), "nan": set()}
            for kind in (0, *FINITE):
                if (bad := _garbage(x, kind)) is not None:
                    out = _paths(jax.device_get(step(_replace(s, path, bad), action)))
                    changed["nan" if kind == 0 else "finite"] |= set(_changed(base, out))
            fields[path.removeprefix(".data.")] = {k: sorted(v) for k, v in changed.items()}
        result["modes"][mode] = fields
    result["read"] = fixed_point(result, impl, "finite")
    result["read_with_nan"] = fixed_point(result, impl, "nan")
    declared = env.previous_state_reads
    result["declared"] = None if declared is None else sorted(declared)
    result["undeclared"] = None if declared is None else sorted(set(result["read"]) - set(declared))
    result["seconds"] = round(time.time() - t, 1)
    return result


def _used(out: str, kept: set[str]) -> bool:
    """Whether output `out` is one training uses: not a physics field, or a kept one."""
    for prefix in (".data", ".info['first_data']"):
        if out.startswith(prefix + "."):
            return _field(out.removeprefix(prefix)) in kept
    return True


def fixed_point(result: dict[str, Any], impl: str, kind: str) -> list[str]:
    """The fields (as tasks name them) a step reads: grown until no field outside the set changes
    an output that training uses or a field kept (of the current or the first state)."""
    always = set(mjx_physics.ALWAYS_KEPT if impl != "c" else STATE)
    kept = set(always)
    while True:
        more = {
            _field("." + leaf)
            for mode in result["modes"].values()
            for leaf, outs in mode.items()
            if any(_used(out, kept) for out in outs[kind])
        }
        if more <= kept:
            return sorted(kept - always)
        kept |= more


def joint(name: str, impl: str, overrides: dict[str, Any] | None = None, steps: int = 3) -> dict[str, Any]:
    """Every field a checkpoint leaves out (`physics.derived_paths`) is garbage, in the current
    and first states, for `steps` steps ending an episode (from a normal and from a blown-up
    step): every output training uses and every kept field must be bit-identical."""
    env, _, step, state, action = _setup(name, impl, False, overrides or {})
    dropped = physics.derived_paths(state, env.previous_state_reads)

    def spoil(s: Any, kind: int) -> Any:
        for p in dropped:
            s = _replace(s, p, _garbage(np.asarray(_paths(s)[p]), kind))
        return s

    bad = []
    for label, start in (("normal", state), ("blow_up", _blow_up(state))):
        start.info["steps"] = np.full_like(start.info["steps"], 1000 - 2)  # the episode ends at the 2nd step
        for kind in FINITE[:2]:
            a, b = start, spoil(start, kind)
            for i in range(steps):
                a, b = step(a, action), step(b, action)
                differ = _changed(_paths(jax.device_get(a)), _paths(jax.device_get(b)))
                bad += [f"{label}, kind {kind}, step {i}: {k}" for k in differ if k not in dropped]
    return {"env": name, "impl": impl, "set": overrides or {}, "dropped": len(dropped), "differs": bad}


def recompute(name: str) -> dict[str, Any]:
    """Each non-integration field of a state after a training step (current, and first: from a
    reset) vs the same field recomputed from its integration state by `sync` and by `mjx.forward`,
    each jitted on its own: identical, differs, or not recomputed."""
    from vnl.quiet_mjx import mjx

    env, _, _, state, _ = _setup(name, "jax", False, {})
    model = env.mjx_model
    out: dict[str, Any] = {"env": name}
    for label, data in (("current", state.data), ("first", state.info["first_data"])):
        data = jax.tree.map(jp.asarray, data)
        fresh = jax.vmap(lambda _: mjx.make_data(model))(data.time)
        bare = fresh.replace(**{f: getattr(data, f) for f in mjx_physics.INTEGRATION})
        redone = {
            "sync": _paths(jax.jit(jax.vmap(lambda d: mjx_physics.sync(model, d)))(bare)),
            "forward": _paths(jax.jit(jax.vmap(lambda d: mjx.forward(model, d)))(bare)),
        }
        saved, blank = _paths(data), _paths(bare)
        for how, fields in redone.items():
            out[f"{label}/{how}"] = {
                p: _bits(saved[p], fields[p])
                if _bits(blank[p], fields[p]) != "identical" or not np.any(saved[p])
                else "not recomputed"
                for p in saved
                if _field(p) not in mjx_physics.INTEGRATION and np.size(saved[p])
            }
    return out


def _bits(a: Any, b: Any) -> str:
    a, b = np.asarray(a), np.asarray(b)
    if a.tobytes() == b.tobytes():
        return "identical"
    return f"differs (max |diff| {float(np.nanmax(np.abs(a.astype(np.float64) - b))):.3g})"


def sizes() -> list[dict[str, Any]]:
    """Checkpoint bytes (MiB) before and after compact env states, gpu and cpu presets."""
    from vnl.train import config as train_config
    from vnl.train import rundir

    rows = []
    for name in ("rodent_run", "humanoid_run", "ant_run"):
        for preset in ("gpu", "cpu"):
            config = train_config.build(name, preset)
            env = config.make_env()
            full = rundir.checkpoint_bytes(config, env, compact=False)
            compact = rundir.checkpoint_bytes(config, env)
            rows.append({
                "env": name, "preset": preset, "num_envs": config.ppo.num_envs,
                "impl": config.env_config.get("impl", "jax"),
                "full_MiB": round(full / 2**20, 1), "compact_MiB": round(compact / 2**20, 1),
            })  # fmt: skip
            print(json.dumps(rows[-1]), flush=True)
    return rows


def _brief(result: dict[str, Any]) -> dict[str, Any]:
    """What the console shows of a result: no per-field tables (`--out` has them)."""
    brief = {k: v for k, v in result.items() if k != "modes" and not isinstance(v, dict)}
    for k, v in result.items():
        if isinstance(v, dict) and k != "modes" and k != "set":
            counts: dict[str, int] = {}
            for verdict in v.values():
                counts[verdict.split(" ")[0]] = counts.get(verdict.split(" ")[0], 0) + 1
            brief[k] = counts
    return brief | ({"set": result["set"]} if result.get("set") else {})


def _overrides(pairs: list[str]) -> dict[str, Any]:
    """`--set key=value` pairs as env config overrides (values read as JSON where they parse)."""
    out = {}
    for pair in pairs:
        key, _, value = pair.partition("=")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def compressed(name: str, impl: str, batch: int = 64, steps: int = 50) -> dict[str, Any]:
    """A checkpoint's env arrays of `batch` envs after `steps` random training steps, compact, as
    `np.savez` and `np.savez_compressed` write them: bytes per env."""
    import io

    env = registry.make(name, impl=impl)
    wrapped = wrap_for_training(env, episode_length=1000)

    @jax.jit
    def run(key: jax.Array) -> Any:
        k0, k1 = jax.random.split(key)
        state = wrapped.reset(jax.random.split(k0, batch))
        actions = jax.random.uniform(k1, (steps, batch, env.action_size), minval=-1, maxval=1)
        return jax.lax.scan(lambda s, a: (wrapped.step(s, a), None), state, actions)[0]

    state = jax.device_get(run(jax.random.PRNGKey(0)))
    dropped = set(physics.derived_paths(state, env.previous_state_reads))
    arrays = {k: np.asarray(x) for k, x in _paths(state).items() if k not in dropped}
    out: dict[str, Any] = {"env": name, "impl": impl, "batch": batch, "steps": steps}
    out["arrays"] = sum(x.nbytes for x in arrays.values()) // batch
    for label, write in (("savez", np.savez), ("savez_compressed", np.savez_compressed)):
        buffer = io.BytesIO()
        write(buffer, **arrays)
        out[label] = len(buffer.getvalue()) // batch
    out["ratio"] = round(out["savez_compressed"] / out["savez"], 2)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--reads", nargs="*", metavar="ENV", help="envs (default: every registered env)")
    mode.add_argument("--joint", nargs="*", metavar="ENV", help="envs (default: every registered env)")
    mode.add_argument("--recompute", nargs="+", metavar="ENV")
    mode.add_argument("--sizes", action="store_true")
    mode.add_argument("--compressed", nargs="+", metavar="ENV")
    parser.add_argument("--impl", choices=("jax", "c"), default="jax")
    parser.add_argument("--vision", action="store_true", help="--reads: the envs with their camera")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="an env config override")
    parser.add_argument("--out", type=Path, help="a JSON file of the results (rewritten after each env)")
    args = parser.parse_args()
    overrides = _overrides(args.set)
    results: list[Any] = []
    header = {"date": datetime.date.today().isoformat(), "argv": sys.argv[1:], "jax": jax.__version__}
    if args.sizes:
        results = sizes()
    kinds = (("reads", args.reads), ("joint", args.joint), ("recompute", args.recompute))
    for kind, envs in (*kinds, ("compressed", args.compressed)):
        every = [n for n in registry.names() if not registry.is_suite(n)]  # a suite: its members' rows
        for name in every if envs == [] else envs or []:
            if kind == "reads":
                results.append(reads(name, args.impl, args.vision, overrides))
            elif kind == "joint":
                results.append(joint(name, args.impl, overrides))
            elif kind == "compressed":
                results.append(compressed(name, args.impl))
            else:
                results.append(recompute(name))
            print(json.dumps(_brief(results[-1])), flush=True)
            if args.out:
                args.out.write_text(json.dumps({**header, "results": results}, indent=1))
    if args.out:
        args.out.write_text(json.dumps({**header, "results": results}, indent=1))


if __name__ == "__main__":
    main()
