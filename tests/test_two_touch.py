"""rodent_two_touch against dm_control's own `reach.TwoTouch` (basic_rodent_2020.rodent_two_touch).

Both are driven kinematically through the same scripted trials: at every control step the rat is
placed (default pose, root moved) so that its left hand's ellipsoid sits at a given offset from
the orb, inside it for a touch. dm_control's task runs as its `composer.Environment` would run it
(`before_step`, the orb's `after_substep` after each of its 20 physics steps of 1 ms, `get_reward`),
vnl's through `prepare` and `react`, the two halves of its `step`. Compared per step: the observed
`task_logic`, the state after the step, the reward, and when the orb moves.

dm_control compares times as float64 sums of 1-ms steps, so at the rules' exact boundaries (a
window of 45 steps, a timeout of 60) its outcome depends on the trial's start time; vnl counts
whole steps. The scripted trials start where dm_control's rounding agrees with exact arithmetic,
and `test_at_the_exact_boundaries_dm_control_rounds_and_vnl_counts_steps` shows the rest.
"""

import functools
import types

import jax
import jax.numpy as jp
import mujoco
import numpy as np
import pytest

import vnl
from vnl.tasks import two_touch
from vnl.tasks.touch import TouchGeoms

pytestmark = pytest.mark.xdist_group("rodent_two_touch-c")

HAND = "walker/hand_L_collision"  # the geom the scripts place; dm_control's hand_L ellipsoid
TOUCH = np.array([0.004, 0.003, -0.002])  # the hand's centre inside the orb (not concentric: see touch_rule)
AWAY = [np.array(v) for v in ([0.0, 0.0, 0.1], [0.15, 0.0, 0.05], [0.3, 0.2, 0.1], [0.08, -0.06, 0.04])]
LOGIC = ["pre_touch", "touched_once", "touched_twice", "touched_too_soon", "no_second_touch"]


@functools.cache
def env():
    return vnl.make("rodent_two_touch", impl="c")


def _dm_env():
    """dm_control's reference env as basic_rodent_2020 builds it (its camera renders when it is built)."""
    from dm_control.locomotion.examples import basic_rodent_2020

    try:
        dm = basic_rodent_2020.rodent_two_touch(random_state=np.random.RandomState(0))
        dm.reset()
    except (mujoco.FatalError, ImportError, RuntimeError) as err:
        pytest.skip(f"dm_control's rodent_two_touch renders its egocentric camera and needs OpenGL: {err}")
    return dm


def _dm_times(steps):
    """dm_control's physics time at each control step 0..steps: 20 additions of 1 ms per step, in
    float64, as mj_step adds its timestep."""
    t, times = 0.0, [0.0]
    for _ in range(steps):
        for _ in range(20):
            t += 0.001
        times.append(t)
    return np.asarray(times)


class DmDriver:
    """dm_control's task, stepped with scripted rat placements instead of its physics."""

    def __init__(self):
        from dm_control.locomotion.props import target_sphere

        self.env = _dm_env()
        self.physics, self.task = self.env.physics, self.env.task
        self.target = next(
            e for e in self.task.root_entity.iter_entities() if isinstance(e, target_sphere.TargetSphereTwoTouch)
        )
        self.rs = np.random.RandomState(1)
        m = self.physics.model
        self.hand = m.name2id(HAND, "geom")
        self.root = next(int(m.jnt_qposadr[j]) for j in range(m.njnt) if m.jnt_type[j] == 0)
        self.qpos0 = np.array(m.qpos0)
        self.physics.data.qpos[:] = self.qpos0
        self.physics.forward()
        self.offset = self.physics.data.geom_xpos[self.hand] - self.qpos0[self.root : self.root + 3]
        self.substeps = round(self.env.control_timestep() / m.opt.timestep)

    def logic(self):
        return int(self.task.task_observables["task_logic"].observation_callable(self.physics, self.rs)()[0])

    def step(self, offset):
        """One control step with the hand at orb + offset: (observed logic, reward, orb, logic after)."""
        self.task.before_step(self.physics, np.zeros(self.env.action_spec().shape), self.rs)
        observed = self.logic()  # dm_control's observation is taken before get_reward
        self.physics.forward()  # the orb may have moved
        orb = self.physics.bind(self.target.geom).xpos.copy()
        qpos = self.qpos0.copy()
        qpos[self.root : self.root + 3] = orb + offset - self.offset
        self.physics.data.qpos[:] = qpos
        self.physics.forward()
        for _ in range(self.substeps):
            self.physics.data.time += self.physics.model.opt.timestep
            self.target.after_substep(self.physics, self.rs)
        reward = self.task.get_reward(self.physics)
        return observed, float(reward), orb, self.logic()


@functools.cache
def _halves(e):
    """`e.prepare` and `e.react` on a scripted pose (qpos), jitted once per env."""
    react = jax.jit(
        lambda s, q: e.react(s, e.forward(e.make_data(qpos=q, mocap_pos=s.data.mocap_pos)), jp.float32(0.0))
    )
    return jax.jit(e.prepare), react


class VnlDriver:
    """vnl's env, stepped with the same placements (`prepare`, a scripted physics state, `react`)."""

    def __init__(self, e, seed=0):
        self.env = e
        self.state = jax.jit(e.reset)(jax.random.PRNGKey(seed))
        m = e.mj_model
        self.root = e._free_qpos
        self.qpos0 = np.array(m.qpos0, np.float32)
        hand = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, HAND)
        d = jax.jit(lambda q: e.forward(e.make_data(qpos=q)))(jp.asarray(self.qpos0))
        self.offset = np.asarray(d.geom_xpos[hand]) - self.qpos0[self.root : self.root + 3]
        start = sum(w for _, w in e.observation_layout()[:-1])
        assert e.observation_layout()[-1] == ("task_logic", 1)
        self.logic_index = start
        self._prepare, self._react = _halves(e)

    def step(self, offset):
        s = self._prepare(self.state)
        orb = np.asarray(self.env.orb(s.data))
        qpos = self.qpos0.copy()
        qpos[self.root : self.root + 3] = orb + offset - self.offset
        self.state = self._react(s, jp.asarray(qpos))
        st = self.state
        return int(st.obs[self.logic_index]), float(st.reward), orb, int(st.metrics["task_logic"])


def _failure_step(trial, a):
    """The step of a failed trial's failure (first touch at `a`); None for a pair."""
    kind = trial[0]
    if kind == "too_soon":
        return a + trial[1]
    return {"held": a + 10, "none": a + 46, "late": a + 46}.get(kind)


def script(trials, gap=3, times=None):
    """Touch steps for `trials`, each starting `gap` steps after the orb moved (or the start), at
    the first step from there where dm_control's float64 times agree with exact arithmetic at the
    trial's boundaries. A trial: ("pair", n) a second touch n steps after the first; ("too_soon",
    n); ("none",) no second touch; ("held", n) a touch held for n steps; ("debounce", n, m) a touch
    n steps after the first (within the debounce) and another m after it; ("late", n) one n steps
    after the first, past the window. Returns (touch steps, last step, expected measure sums,
    expected intervals in steps)."""
    times = _dm_times(3000) if times is None else times
    touches, counts, intervals = set(), dict.fromkeys(("first", "pair", "soon", "none"), 0), []
    a = gap
    for trial in trials:
        kind = trial[0]

        while True:
            s = _failure_step(trial, a)
            window_ok = times[a + 45] - times[a] <= 0.9  # dm_control would close the window one step early
            timeout_ok = s is None or not times[s + 60] > times[s] + 1.2  # ... end its timeout one step early
            if window_ok and timeout_ok:
                break
            a += 1
        counts["first"] += 1
        if kind == "pair":
            touches |= {a, a + trial[1]}
            counts["pair"] += 1
            intervals.append(trial[1])
            moved = a + trial[1] + 2  # flagged the step after the pair, moved at the next
        elif kind == "debounce":
            touches |= {a, a + trial[1], a + trial[1] + trial[2]}
            counts["pair"] += 1
            intervals.append(trial[1] + trial[2])
            moved = a + trial[1] + trial[2] + 2
        else:
            if kind == "too_soon":
                touches |= {a, a + trial[1]}
            elif kind == "held":
                touches |= set(range(a, a + trial[1]))
            elif kind == "none":
                touches |= {a, a + 70}  # a touch during the timeout, ignored
            else:  # late
                touches |= {a, a + trial[1]}
            counts["soon" if kind in ("too_soon", "held") else "none"] += 1
            if kind in ("too_soon", "held"):
                intervals.append(s - a)
            moved = s + 63  # the timeout ends after 60 steps; flagged at 62, moved at 63
        a = moved + gap
    return touches, a, counts, intervals


def drive(drivers, touches, steps):
    """Steps every driver through `steps` control steps (touching at `touches`); per driver a list
    of (observed logic, reward, orb, logic after) per step, steps numbered from 1."""
    out = [[] for _ in drivers]
    for k in range(1, steps + 1):
        offset = TOUCH if k in touches else AWAY[k % len(AWAY)]
        for record, driver in zip(out, drivers, strict=True):
            record.append(driver.step(offset))
    return out


def test_the_touch_is_dm_controls_contact_of_a_hand_ellipsoid_with_the_orb():
    """Random poses of the rat and orb positions around its hand and finger geoms: vnl's geometric
    test says touch exactly where dm_control's contact list holds a hand geom against the orb. In
    dm_control (MuJoCo 3.17) only the hand ellipsoids ever do: MuJoCo's mid-phase drops the finger
    capsules' pairs (their body's bounding boxes, with the two geoms' margins added, -2r, never
    overlap); with the mid-phase disabled they appear. vnl's `hands` bodies' own geoms are the
    ellipsoids."""
    e = env()
    dm = _dm_env()
    p = dm.physics
    dmm, dmd = p.model.ptr, p.data.ptr
    orb = p.model.name2id("target_0_0/geom", "geom")
    hand_names = [f"walker/{n}_collision" for s in "LR" for n in (f"hand_{s}", *(f"finger_{s}{i}" for i in range(3)))]
    dm_hands = [dmm.geom(n).id for n in hand_names]
    m = e.mj_model
    assert sorted(m.geom(int(g)).name for g in e._touch.ids) == ["walker/hand_L_collision", "walker/hand_R_collision"]
    vnl_hands = [m.geom(n).id for n in hand_names]
    hinges = [
        (int(m.jnt_qposadr[j]), int(dmm.joint(m.joint(j).name).qposadr[0]), j) for j in range(m.njnt) if m.jnt_type[j]
    ]
    root, dm_root = e._free_qpos, next(int(dmm.jnt_qposadr[j]) for j in range(dmm.njnt) if dmm.jnt_type[j] == 0)
    make = jax.jit(lambda q, mp: e.forward(e.make_data(qpos=q, mocap_pos=mp)))
    touches = jax.jit(e.touches)
    rng = np.random.default_rng(0)
    outcomes = []
    for _ in range(200):
        q = np.array(m.qpos0)
        for a, _, j in hinges:
            lo, hi = m.jnt_range[j]
            q[a] = rng.uniform(lo, hi) if m.jnt_limited[j] else rng.uniform(-0.5, 0.5)
        yaw = rng.uniform(-np.pi, np.pi)
        q[root : root + 7] = [0.1, -0.2, 0.2, np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)]
        dmd.qpos[:] = 0
        dmd.qpos[dm_root : dm_root + 7] = q[root : root + 7]
        for a, b, _ in hinges:
            dmd.qpos[b] = q[a]
        mujoco.mj_forward(dmm, dmd)
        g = rng.integers(len(hand_names))
        direction = rng.normal(size=3)
        point = dmd.geom_xpos[dm_hands[g]] + direction / np.linalg.norm(direction) * rng.uniform(0.0, 0.045)
        dmm.geom_pos[orb] = point
        mujoco.mj_forward(dmm, dmd)
        listed = any(
            orb in (c.geom1, c.geom2) and ({c.geom1, c.geom2} & set(dm_hands)) for c in dmd.contact[: dmd.ncon]
        )
        data = make(jp.asarray(q, jp.float32), jp.asarray(point[None], jp.float32))
        np.testing.assert_allclose(np.asarray(data.geom_xpos)[vnl_hands], dmd.geom_xpos[dm_hands], atol=1e-5)
        depth = min(mujoco.mj_geomDistance(dmm, dmd, h, orb, 0.1, None) for h in dm_hands[::4])
        if abs(depth) > 1e-5:  # not grazing
            outcomes.append((bool(touches(data)), listed))
    # The orb on a finger: no finger contact, unless the mid-phase is off.
    finger = dm_hands[1]
    dmm.geom_pos[orb] = dmd.geom_xpos[finger]
    for midphase_off, listed in ((False, False), (True, True)):
        dmm.opt.disableflags = mujoco.mjtDisableBit.mjDSBL_MIDPHASE if midphase_off else 0
        mujoco.mj_forward(dmm, dmd)
        assert any({orb, finger} == {c.geom1, c.geom2} for c in dmd.contact[: dmd.ncon]) == listed
    dmm.opt.disableflags = 0
    outcomes = np.asarray(outcomes)
    assert (outcomes[:, 0] == outcomes[:, 1]).all(), outcomes[outcomes[:, 0] != outcomes[:, 1]]
    assert 50 < outcomes[:, 0].sum() < len(outcomes) - 50  # both touches and misses were tried


def test_scripted_trials_give_dm_controls_rewards_states_and_redraws():
    """Every path of the task's state machine, in one episode, in both: a pair; a second touch
    too soon; no second touch (the window closes, a touch in the timeout is ignored); a touch held
    past the debounce (too soon); a touch inside the debounce, then a timely one (a pair); a touch
    after the window (too late: the window had closed)."""
    trials = [("pair", 40), ("too_soon", 20), ("none",), ("held", 15), ("debounce", 5, 33), ("late", 50), ("pair", 36)]
    touches, steps, counts, intervals = script(trials)
    e = env()
    dm, vn = drive([DmDriver(), VnlDriver(e)], touches, steps)
    observed_dm, reward_dm, orb_dm, after_dm = zip(*dm, strict=True)
    observed_vnl, reward_vnl, orb_vnl, after_vnl = zip(*vn, strict=True)
    for k in range(steps):
        where = f"step {k + 1}: dm_control {LOGIC[after_dm[k]]}, vnl {LOGIC[after_vnl[k]]}"
        assert (observed_vnl[k], after_vnl[k]) == (observed_dm[k], after_dm[k]), where
        assert reward_vnl[k] == pytest.approx(reward_dm[k], abs=2e-4), where
    moved_dm = [k + 1 for k in range(1, steps) if np.abs(orb_dm[k] - orb_dm[k - 1]).max() > 0]
    moved_vnl = [k + 1 for k in range(1, steps) if np.abs(orb_vnl[k] - orb_vnl[k - 1]).max() > 0]
    assert moved_vnl == moved_dm and len(moved_dm) == len(trials)
    # The paths were taken, and the measures count them.
    assert set(after_dm) == set(range(5))
    big = np.asarray(reward_dm) > 20
    assert big.sum() == counts["first"] + counts["pair"]  # 25 for each first touch and each correct pair
    assert np.all(np.asarray(reward_dm)[~big] <= 0.25)  # the closeness term alone elsewhere


def test_the_measures_count_the_trials_and_keep_every_inter_touch_interval():
    trials = [("pair", 40), ("too_soon", 20), ("none",), ("held", 15), ("pair", 44), ("late", 50)]
    touches, steps, counts, intervals = script(trials)
    e = env()
    driver = VnlDriver(e)
    rows = []
    for k in range(1, steps + 1):
        driver.step(TOUCH if k in touches else AWAY[k % len(AWAY)])
        rows.append({key: float(v) for key, v in driver.state.metrics.items()})
    total = {key: sum(r[key] for r in rows) for key in rows[0]}
    assert total["measure/first_touches"] == counts["first"] == len(trials)
    assert total["measure/correct_pairs"] == counts["pair"]
    assert total["measure/too_soon"] == counts["soon"]
    assert total["measure/no_second_touch"] == counts["none"]
    recorded = [r["touch_interval"] for r in rows if r["touch_interval"] > 0]
    np.testing.assert_allclose(recorded, np.asarray(intervals) * e.dt, rtol=1e-6)
    assert (
        total["reward/first_touch"] == 25.0 * counts["first"] and total["reward/second_touch"] == 25.0 * counts["pair"]
    )


def test_at_the_exact_boundaries_dm_control_rounds_and_vnl_counts_steps():
    """A first touch with no second: the window (0.9 s) closes 46 steps after it in vnl; in
    dm_control, whose times are float64 sums of 1-ms steps, after 45 for first touches where the
    sum of 45 steps exceeds 0.9 (about 60% of them), else after 46."""
    times = _dm_times(200)
    early = next(a for a in range(3, 150) if times[a + 45] - times[a] > 0.9)
    exact = next(a for a in range(3, 150) if not times[a + 45] - times[a] > 0.9)
    for a, dm_closes in ((early, 45), (exact, 46)):
        dm, vn = drive([DmDriver(), VnlDriver(env())], {a}, a + 47)
        closed_dm = next(k for k, (_, _, _, after) in enumerate(dm, 1) if after == two_touch.NO_SECOND_TOUCH)
        closed_vnl = next(k for k, (_, _, _, after) in enumerate(vn, 1) if after == two_touch.NO_SECOND_TOUCH)
        assert (closed_dm - a, closed_vnl - a) == (dm_closes, 46)
        assert [r[3] for r in dm[: a + 44]] == [r[3] for r in vn[: a + 44]]


def test_rule_times_in_control_steps():
    e = env()
    assert e.dt == pytest.approx(0.02)
    assert e.rule_steps == {"too_soon_below": 35, "window_last": 45, "timeout": 60, "delay": 0, "debounce": 10}


def test_orbs_are_drawn_in_the_target_area_and_the_rat_faces_any_way():
    e = env()
    states = jax.jit(jax.vmap(e.reset))(jax.random.split(jax.random.PRNGKey(3), 512))
    orbs = np.asarray(jax.vmap(e.orb)(states.data))
    assert np.all(np.abs(orbs[:, :2]) <= 1.5) and np.allclose(orbs[:, 2], 0.14)
    assert orbs[:, :2].std(0) == pytest.approx([np.sqrt(3.0) / 2] * 2, rel=0.1)  # uniform in ±1.5
    quat = np.asarray(states.data.qpos[:, 3:7])
    yaw = 2 * np.arctan2(quat[:, 3], quat[:, 0])
    yaw = (yaw + np.pi) % (2 * np.pi) - np.pi
    assert np.histogram(yaw, bins=8, range=(-np.pi, np.pi))[0].min() > 30  # every direction
    # Redraws within an episode: new points from the episode's key and the step.
    redraws = jax.vmap(lambda t: e.draw_orb(jax.random.fold_in(states.info["rng"][0], t)))(jp.arange(64))
    assert len({tuple(np.round(r, 5)) for r in np.asarray(redraws)}) == 64


def test_a_walker_without_the_hands_names_them():
    with pytest.raises(vnl.VnlError, match="hands: no body named"):
        vnl.make("rodent_two_touch", impl="c", walker="ant")
    with pytest.raises(vnl.VnlError, match="interval_tolerance < touch_interval"):
        vnl.make("rodent_two_touch", impl="c", interval_tolerance=0.9)


@pytest.mark.parametrize("shape", ["sphere", "capsule", "ellipsoid", "box", "cylinder"])
def test_touch_distances_are_mujocos(shape):
    """`TouchGeoms.distance` from random points to a tilted geom of each shape, against MuJoCo's
    own `mj_geomDistance` to a tiny sphere at the point."""
    size = {"sphere": "0.03", "capsule": "0.02 0.05", "ellipsoid": "0.04 0.02 0.01", "box": "0.03 0.02 0.05"}
    size["cylinder"] = "0.03 0.04"
    xml = f"""<mujoco><worldbody>
      <body name="b" pos="0.1 0.2 0.3" euler="20 40 60"><geom name="g" type="{shape}" size="{size[shape]}"/></body>
      <body name="p" mocap="true"><geom name="p" type="sphere" size="1e-6" contype="0" conaffinity="0"/></body>
    </worldbody></mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    geoms = TouchGeoms.of(m, [1])
    distance = jax.jit(lambda xpos, xmat, p: geoms.distance(types.SimpleNamespace(geom_xpos=xpos, geom_xmat=xmat), p))
    rng = np.random.default_rng(1)
    for _ in range(50):
        d.mocap_pos[0] = np.array([0.1, 0.2, 0.3]) + rng.normal(size=3) * 0.05
        mujoco.mj_forward(m, d)
        want = max(mujoco.mj_geomDistance(m, d, 0, 1, 1.0, None) + 1e-6, 0.0)
        got = float(distance(jp.asarray(d.geom_xpos), jp.asarray(d.geom_xmat).reshape(-1, 3, 3), d.mocap_pos[0])[0])
        assert got == pytest.approx(want, abs=2e-5), d.mocap_pos[0]
