"""The navigation MDP through Gymnasium and dm_control: spaces, determinism, rewards, termination."""

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import mjendo  # noqa: F401  (registers the ids)
from mjendo import targets
from mjendo.baseline import DLSController
from mjendo.config import ConfigError
from mjendo.envs import EndoscopeEnv
from mjendo.policies import PolicyError, load_controller
from mjendo.rollout import episode, run

IDS = [f"mjendo/{e}-v{v}" for v in (1, 0) for e in ("FE", "SE", "DE", "UE1", "UE2")] + ["endogym-v0"]


@pytest.mark.parametrize("env_id", IDS)
def test_check_env(env_id):
    env = gym.make(env_id, force_obs=env_id.endswith("DE-v1"))
    check_env(env.unwrapped, skip_render_check=True)


@pytest.mark.parametrize("env_id", IDS)
def test_every_id_is_deterministic_under_a_seed_and_seeds_differ(env_id):
    def trajectory(seed):
        env = gym.make(env_id).unwrapped
        obs, info = env.reset(seed=seed)
        rng = np.random.default_rng(0)
        out = [obs] + [env.step(rng.uniform(-0.4, 0.4, 5))[0] for _ in range(3)]
        return info["target_index"], np.array(out)

    (t1, a), (t2, b) = trajectory(11), trajectory(11)
    assert t1 == t2
    np.testing.assert_array_equal(a, b)
    assert any(not np.array_equal(trajectory(s)[1][0], a[0]) for s in (12, 13, 14))


def test_ids_carry_their_task_version():
    assert gym.make("mjendo/DE-v1").unwrapped.task.cfg.version == 1
    assert gym.make("mjendo/DE-10ms-v2").unwrapped.task.cfg.version == 2
    old = gym.make("mjendo/DE-v0").unwrapped.task
    assert old.cfg.version == 0 and old.cfg.control_period_s == 0.03 and old.sim.pivot < 0
    new = gym.make("mjendo/DE-v1").unwrapped.task
    assert new.cfg.control_period_s == 0.1 and new.sim.pivot >= 0


def test_the_current_version_is_gymnasiums_latest():
    """Version 2 is an alternative, not a successor: mjendo/DE must mean version 1, and v1 must not warn."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gym.make("mjendo/DE-v1")
    with pytest.warns(UserWarning, match="mjendo/DE-v1"):
        assert gym.make("mjendo/DE").unwrapped.task.cfg.version == 1
    with pytest.warns(DeprecationWarning, match="out of date"):
        gym.make("mjendo/DE-v0")


def seeded_trajectory(seed, steps=20, env_name="DE"):
    env = EndoscopeEnv(env_name)
    rng = np.random.default_rng(123)
    obs, info = env.reset(seed=seed)
    out = [obs]
    for _ in range(steps):
        obs, *_ = env.step(rng.uniform(-0.4, 0.4, 5))
        out.append(obs)
    return info["target_index"], np.array(out)


def test_same_seed_same_trajectory_and_seeds_vary_targets():
    t1, a = seeded_trajectory(7)
    t2, b = seeded_trajectory(7)
    assert t1 == t2
    np.testing.assert_array_equal(a, b)
    env = EndoscopeEnv("SE")
    targets = {env.reset(seed=s)[1]["target_index"] for s in range(8)}
    assert len(targets) >= 3


def test_observations_change_and_do_not_share_memory():
    env = EndoscopeEnv("DE")
    obs0, _ = env.reset(seed=1)
    obs1, _, _, _, info1 = env.step(np.full(5, 0.4))
    obs2, _, _, _, info2 = env.step(np.full(5, 0.4))
    assert not np.allclose(obs1, obs2)
    assert not np.shares_memory(obs1, obs2) and not np.shares_memory(obs0, obs1)
    assert not np.shares_memory(info1["force_N"], info2["force_N"])
    assert obs1.dtype == np.float32 and env.observation_space.contains(obs1)


def test_reward_is_minus_distance_on_ordinary_steps():
    env = EndoscopeEnv("DE")
    env.reset(seed=3)
    for _ in range(5):
        _, r, term, _, info = env.step(np.zeros(5))
        assert not term
        assert r == pytest.approx(-info["distance_mm"])
        # The observation's tip-to-target vector has the reported length.
    obs = env.task.observation()
    assert np.linalg.norm(obs[:3]) == pytest.approx(info["distance_mm"], rel=1e-4)


def test_distance_weight_scales_the_distance_term_and_nothing_else():
    paper, light = EndoscopeEnv("DE"), EndoscopeEnv("DE", distance_weight=0.1)
    paper.reset(seed=3)
    light.reset(seed=3)
    for _ in range(5):
        _, r1, _, _, i1 = paper.step(np.array([0.2, 0, 0, 0, 0.4]))
        _, r2, _, _, i2 = light.step(np.array([0.2, 0, 0, 0, 0.4]))
        assert i2["distance_mm"] == pytest.approx(i1["distance_mm"])  # the same physics
        assert r2 == pytest.approx(0.1 * r1) and i2["reward_distance"] == pytest.approx(-0.1 * i1["distance_mm"])


def test_success_bonus_fires_and_terminates():
    env = EndoscopeEnv("FE")
    env.reset(seed=0)
    # Construct the case: put the (free-floating) target 1 mm ahead of the tip.
    env.task._fe_targets = env.task._fe_targets.copy()
    corners = env.task.target_tri[env.task._row]  # the target is a point on this lumen triangle
    env.task._fe_targets[corners] = env.task.sim.tip_pos() + 0.001 * env.task.sim.tip_axis()
    _, r, term, trunc, info = env.step(np.zeros(5))
    assert info["is_success"] and term and not trunc
    assert r == pytest.approx(1e4 - info["distance_mm"])


def test_leaving_through_the_cardia_is_penalised_and_terminates():
    env = EndoscopeEnv("SE")
    env.reset(seed=0)
    for _ in range(40):
        _, r, term, trunc, info = env.step(np.array([0, 0, 0, 0, -0.4]))
        if term:
            break
    assert term and info["exited"] and not info["is_success"]
    assert env.task.tip_x_mm() < 15.0
    assert r == pytest.approx(-1e4 - info["distance_mm"])


def test_episode_truncates_at_max_steps():
    env = EndoscopeEnv("SE", max_steps=6)
    env.reset(seed=0)
    flags = [env.step(np.zeros(5))[3] for _ in range(6)]
    assert flags == [False] * 5 + [True]


def test_target_moves_with_the_wall_in_de_not_in_se():
    def travel(name):
        env = EndoscopeEnv(name, randomize_phase=False)
        env.reset(seed=0)
        env.task.insertion = env.task.sim.insertion_range[0]  # keep the scope off the wall
        p = [env.task.target_pos()]
        for _ in range(25):  # 2.5 s: the load reverses at 2 s
            env.step(np.array([0, 0, 0, 0, -0.0]))
            p.append(env.task.target_pos())
        p = np.array(p)
        return np.linalg.norm(p - p[0], axis=1).max() * 1e3

    assert travel("DE") > 0.5
    assert travel("SE") < 0.2


def test_force_blind_observation_is_the_aware_one_without_force():
    # Same seed and actions: the same physics; the blind observation must equal the aware one's first 11
    # values at every step, and only the aware one sees the wall push back.
    blind, aware = EndoscopeEnv("SE", force_obs=False), EndoscopeEnv("SE", force_obs=True)
    assert blind.observation_space.shape == (11,) and aware.observation_space.shape == (15,)
    ob, _ = blind.reset(seed=0)
    oa, _ = aware.reset(seed=0)
    np.testing.assert_array_equal(ob, oa[:11])
    for _ in range(70):  # push straight in until the wall resists (an episode that ended is not stepped on)
        ob, _, tb, _, ib = blind.step(np.array([0, 0, 0, 0, 0.4]))
        oa, _, ta, _, ia = aware.step(np.array([0, 0, 0, 0, 0.4]))
        assert not (tb or ta), "the episode ended before the scope reached the wall"
        np.testing.assert_array_equal(ob, oa[:11])
        assert ib["contact"] == ia["contact"]
        if ia["contact"] and np.linalg.norm(ia["force_N"]) > 0.05:
            break
    assert ia["contact"]
    assert oa[11] == 1.0 and np.linalg.norm(oa[12:]) > 0.05  # the aware policy sees it
    np.testing.assert_allclose(oa[12:], ia["force_N"], rtol=1e-6)  # force / force_ref_n (1 N)


def test_scope_observation_is_the_insertion_and_tip_pose_appended():
    plain, scoped = EndoscopeEnv("DE"), EndoscopeEnv("DE", scope_obs=True)
    assert scoped.observation_space.shape == (22,)
    op, _ = plain.reset(seed=3)
    os_, _ = scoped.reset(seed=3)
    for _ in range(8):
        op, *_ = plain.step(np.array([0.2, 0, 0, 0, 0.4]))
        os_, *_ = scoped.step(np.array([0.2, 0, 0, 0, 0.4]))
    np.testing.assert_array_equal(op, os_[:15])
    sim, task = scoped.task.sim, scoped.task
    assert os_[15] == pytest.approx(sim.insertion() * 1e3, rel=1e-5) and os_[15] > 15.0  # 8 x 2.5 mm fed in
    np.testing.assert_allclose(os_[16:19], (sim.tip_pos() - task.origin) * 1e3, rtol=1e-5)
    assert np.linalg.norm(os_[19:22]) == pytest.approx(1.0, abs=1e-5)


def test_time_observation_counts_down_and_the_limit_then_terminates():
    plain, timed = EndoscopeEnv("DE", max_steps=6), EndoscopeEnv("DE", max_steps=6, time_obs=True)
    assert timed.observation_space.shape == (16,)
    op, _ = plain.reset(seed=3)
    ot, _ = timed.reset(seed=3)
    assert ot[-1] == 1.0
    for k in range(1, 7):
        op, _, term_p, trunc_p, _ = plain.step(np.array([0.2, 0, 0, 0, 0.4]))
        ot, _, term_t, trunc_t, info = timed.step(np.array([0.2, 0, 0, 0, 0.4]))
        np.testing.assert_array_equal(op, ot[:15])  # the same physics and the paper's observation
        assert ot[-1] == pytest.approx(1.0 - k / 6)
    # At the limit the blind task truncates (the episode could go on); the timed one terminates: its
    # observation says no time is left, so nothing follows that state.
    assert trunc_p and not term_p and term_t and not trunc_t and not info["is_success"]


def test_phase_observation_runs_with_the_breathing_load_and_adds_nothing_else():
    plain, phased = EndoscopeEnv("DE"), EndoscopeEnv("DE", phase_obs=True)
    assert phased.observation_space.shape == (17,)
    op, _ = plain.reset(seed=5)
    oq, _ = phased.reset(seed=5)
    sim, dt = phased.task.sim, phased.task.control_dt
    angles, loads = [], []
    for _ in range(45):  # 4.5 s: more than one 4 s cycle, so both signs of the load come by
        np.testing.assert_array_equal(op, oq[:15])  # the same physics and the paper's observation
        assert oq[15] ** 2 + oq[16] ** 2 == pytest.approx(1.0, abs=1e-6)
        angles.append(np.arctan2(oq[15], oq[16]))
        op, *_ = plain.step(np.array([0.1, 0, 0, 0, 0.2]))
        oq, *_ = phased.step(np.array([0.1, 0, 0, 0, 0.2]))
        loads.append(sim.data.ctrl[sim.load_act])  # the load applied over that step
    steps = np.diff(np.unwrap(angles))
    np.testing.assert_allclose(steps, 2 * np.pi * dt / (2 * sim.half_period), atol=1e-6)  # one cycle per 4 s
    sines, loads = np.sin(angles), np.array(loads)
    clear = np.abs(sines) > 0.2  # away from the switches, where the sign flips within the step
    assert clear.sum() > 30 and (loads > 0).any() and (loads < 0).any()
    np.testing.assert_array_equal(np.sign(sines[clear]), np.sign(loads[clear]))  # +f0 while the sine is positive


def test_step_observation_is_the_last_command_and_the_tip_displacement_it_made():
    plain, stepped = EndoscopeEnv("DE"), EndoscopeEnv("DE", step_obs=True)
    assert stepped.observation_space.shape == (22,)
    op, _ = plain.reset(seed=5)
    oq, _ = stepped.reset(seed=5)
    np.testing.assert_array_equal(oq[15:], 0.0)  # nothing done yet
    actions = np.array([[0.3, 0.0, -0.2, 0.1, 0.4], [0.0, 0.4, 0.0, -0.4, 0.4], [-0.1, 0.0, 0.2, 0.0, -0.2]] * 4)
    for a in actions:
        tip = stepped.task.sim.tip_pos().copy()
        op, *_ = plain.step(a)
        oq, *_ = stepped.step(a)
        np.testing.assert_array_equal(op, oq[:15])  # the same physics and the paper's observation
        np.testing.assert_allclose(oq[15:19], a[:4], atol=1e-7)
        moved = (stepped.task.sim.tip_pos() - tip) * 1e3
        np.testing.assert_allclose(oq[19:22], moved, atol=1e-4)
        assert np.linalg.norm(moved) > 0.1  # the scope is inserting: every step moves the tip
    # The displacement is the velocity's integral over the step, not the velocity at its end: they differ.
    assert not np.allclose(oq[19:22], oq[3:6] * stepped.task.control_dt, atol=0.05)
    oq, _ = stepped.reset(seed=6)
    np.testing.assert_array_equal(oq[15:], 0.0)  # a new episode forgets the last one's step


def _nearest_face(origin: np.ndarray, ray: np.ndarray, corners: np.ndarray) -> float:
    """Distance along ``ray`` to the nearest of the triangles ``corners`` (n, 3, 3), Moller-Trumbore; inf if none."""
    e1, e2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    p = np.cross(ray, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-15
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = origin - corners[:, 0]
    u = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    v = (q @ ray) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
    return float(t[hit].min()) if hit.any() else np.inf


def test_depth_observation_is_the_walls_distance_along_the_tip_rays():
    # Checked against an independent ray cast over the wall's surface triangles (not MuJoCo's): five rays from
    # the tip camera's lens, 4 mm behind the tip face, along its axis and four tilted 30 degrees towards the
    # bending planes, each clipped at 100 mm.
    plain, seeing = EndoscopeEnv("DE"), EndoscopeEnv("DE", depth_obs=True)
    assert seeing.observation_space.shape == (20,)
    plain.reset(seed=5)
    oq, _ = seeing.reset(seed=5)
    sim = seeing.task.sim
    m, fl = sim.model, sim.flex
    adr = m.flex_shelldataadr[fl]
    shells = m.flex_shell[adr:adr + 3 * m.flex_shellnum[fl]].reshape(-1, 3)  # the wall's surface triangles
    axial = []
    for _ in range(30):
        frame = sim.data.site_xmat[sim.tip_site].reshape(3, 3)
        lens, corners = sim.tip_pos() - 0.004 * frame[:, 2], sim.vertices()[shells]
        c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
        rays = [frame[:, 2]] + [c * frame[:, 2] + sign * s * frame[:, k] for k in (0, 1) for sign in (1, -1)]
        expected = [min(_nearest_face(lens, r, corners) * 1e3, 100.0) for r in rays]
        np.testing.assert_allclose(oq[15:], expected, atol=1e-3)
        axial.append(oq[15])
        op, *_ = plain.step(np.array([0.4, 0.0, 0.0, 0.0, 0.4]))
        oq, *_ = seeing.step(np.array([0.4, 0.0, 0.0, 0.0, 0.4]))
        np.testing.assert_array_equal(op, oq[:15])  # the same physics and the paper's observation
    assert axial[0] == 100.0 and min(axial) < 6.0  # the wall comes into view as the scope bends and inserts
    free = EndoscopeEnv("FE", depth_obs=True)
    np.testing.assert_array_equal(free.reset(seed=5)[0][15:], 100.0)  # no stomach, no wall


def test_normal_observation_is_the_lumen_surface_facing_the_scope_at_the_target():
    # Checked against each target triangle's own face normal from its corners now (not the vertex normals the
    # task blends): the observed normal lies along it, faces the scope (into the lumen, where the tip starts),
    # and turns as the moving wall does.
    plain, seeing = EndoscopeEnv("UE2"), EndoscopeEnv("UE2", normal_obs=True)
    assert seeing.observation_space.shape == (18,)
    task = seeing.task
    seeing.reset(seed=5)
    tip = task.sim.tip_pos()
    for index in task.targets:
        oq, _ = seeing.reset(seed=5, options={"target_index": int(index)})
        corners = task.sim.vertices(task.target_tri[task._row])
        face = np.cross(corners[1] - corners[0], corners[2] - corners[0])
        assert np.linalg.norm(oq[15:]) == pytest.approx(1.0, abs=1e-6)
        assert oq[15:] @ face / np.linalg.norm(face) > 0.95  # along the face normal, on the lumen's side
        assert oq[15:] @ (tip - task.target_pos()) > 0.0  # the scope at the cardia sees the target's face
    plain.reset(seed=5, options={"target_index": int(task.targets[0])})
    first, _ = seeing.reset(seed=5, options={"target_index": int(task.targets[0])})
    turn = 0.0
    for _ in range(40):
        op, *_ = plain.step(np.array([0.4, 0.0, 0.0, 0.0, 0.4]))
        oq, *_ = seeing.step(np.array([0.4, 0.0, 0.0, 0.0, 0.4]))
        np.testing.assert_array_equal(op, oq[:15])  # the same physics and the paper's observation
        corners = task.sim.vertices(task.target_tri[task._row])
        face = np.cross(corners[1] - corners[0], corners[2] - corners[0])
        assert oq[15:] @ face / np.linalg.norm(face) > 0.95
        turn = max(turn, np.degrees(np.arccos(min(float(oq[15:] @ first[15:]), 1.0))))
    assert turn > 0.5  # the wall's motion turns the target's face (degrees)
    free = EndoscopeEnv("FE", normal_obs=True)
    o0, _ = free.reset(seed=5)
    np.testing.assert_allclose(free.step(np.full(5, 0.4))[0][15:], o0[15:], atol=1e-6)  # FE: the static wall's


def test_with_the_force_sensor_off_the_policy_reads_no_contact_while_the_physics_is_unchanged():
    # The ablation of the force inputs: the same pushes into the wall give the same motion and the same paper
    # observation, and where the live sensor reads contact and a force, the one switched off reads 0.
    live, off = EndoscopeEnv("DE"), EndoscopeEnv("DE", force_off=True)
    assert off.observation_space.shape == live.observation_space.shape == (15,)
    live.reset(seed=2, options={"target_index": int(live.task.targets[0])})
    off.reset(seed=2, options={"target_index": int(live.task.targets[0])})
    pushes = 0
    for _ in range(60):
        ol, _, _, _, il = live.step(np.array([0.4, 0.0, 0.0, 0.0, 0.4]))
        oo, _, _, _, io = off.step(np.array([0.4, 0.0, 0.0, 0.0, 0.4]))
        np.testing.assert_array_equal(ol[:11], oo[:11])
        np.testing.assert_array_equal(il["force_N"], io["force_N"])  # the physics and the report see the force
        np.testing.assert_array_equal(oo[11:], 0.0)
        pushes += ol[11] == 1.0 and np.linalg.norm(ol[12:]) > 0.01
    assert pushes > 5


def test_plan_observation_carries_the_maps_way_to_each_target():
    # The observed plan is the map's: free targets say so and need no way; a contact-aided target's way, rebuilt from
    # the seven numbers alone and replayed open loop from the static start, brings the tip within 3 mm of it, where
    # free space never comes within 10 mm. The paper's observation is unchanged and the plan holds over the episode.
    env = EndoscopeEnv("SE", plan_obs=True)
    task, points = env.task, {p["id"]: p for p in targets.read_map(targets.stomach_map())["points"]}
    assert env.observation_space.shape == (22,)
    aided = [int(i) for i in task.targets if points[int(i)]["class"] == "contact_aided"]
    for index in task.targets:
        o, _ = env.reset(seed=1, options={"target_index": int(index)})
        assert o[15] == pytest.approx(points[int(index)]["free_mm"], abs=1e-3)
        assert o[16] == (int(index) in aided)
        if int(index) not in aided:
            np.testing.assert_array_equal(o[17:], 0.0)
    for index in aided[:3]:
        o, _ = env.reset(seed=1, options={"target_index": index})
        plan = o[15:].copy()
        assert plan[0] >= 10.0
        closest = np.inf
        for k in range(80):
            turn = plan[4:6] if np.any(plan[4:6]) and k >= round(plan[6] * 80) else None
            bend = 0.4 * (turn if turn is not None else plan[2:4]) if k < 12 or turn is not None else np.zeros(2)
            o, _, done, _, _ = env.step(np.array([bend[0], -bend[0], bend[1], -bend[1], 0.4]))
            np.testing.assert_array_equal(o[15:], plan)
            closest = min(closest, float(np.linalg.norm(o[:3])))
            if done:
                break
        assert closest < 3.0, (index, closest)
    with pytest.raises(ConfigError, match="plan_obs needs"):
        EndoscopeEnv("SE", plan_obs=True, version=0)


def test_residual_actions_correct_the_baseline_controllers():
    # A policy that adds nothing drives the scope exactly as the DLS baseline does alone; any other action is
    # added, doubled, to the baseline's for the state it observed, and the sum clipped to the action box.
    plain, residual = EndoscopeEnv("DE"), EndoscopeEnv("DE", residual=True)
    assert residual.observation_space.shape == (20,)
    alone = [s.info["distance_mm"] for s in episode(plain, DLSController(plain.task), seed=2)]
    zero = type("Zero", (), {"reset": lambda self, task: None, "act": lambda self, obs, task: np.zeros(5)})()
    corrected = [s.info["distance_mm"] for s in episode(residual, zero, seed=2)]
    assert corrected == alone and alone[-1] < 3.0  # the baseline reaches this target, residual or not
    obs, _ = residual.reset(seed=3)
    base = obs[15:].copy()
    assert np.abs(base).max() > 0.1  # the baseline's action for the start state is observed
    np.testing.assert_allclose(base, residual.task._base.act(None, residual.task), atol=1e-6)
    action = np.array([0.1, -0.4, 0.0, 0.4, -0.4])
    obs, *_ = residual.step(action)
    applied = np.clip(base + 2.0 * action, -0.4, 0.4)
    np.testing.assert_allclose(residual.task.prev_cables, applied[:4], atol=1e-6)
    assert obs[10] == pytest.approx(applied[4], abs=1e-6)  # the previous axial action is the applied one
    assert applied[4] < 0.0 < base[4]  # twice the policy's action reverses an inserting baseline


def test_task_space_actions_move_the_tip_where_they_ask():
    # The action is a tip displacement the DLS controller turns into commands: asked to go 10 mm along an axis,
    # the tip goes that way, by about what one step of the joints allows; asked for the target's direction every
    # step, it arrives as the baseline does. Observations are the paper's; a residual as well is refused.
    env = EndoscopeEnv("FE", task_space=True)
    assert env.action_space.shape == (3,) and env.observation_space.shape == (15,)
    env.reset(seed=4)
    axis = env.task.axis
    for _ in range(8):  # insert first: at the start the bending section lies in the cardia
        env.step(0.4 * axis)
    side = np.cross(axis, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    for direction in (side, -side, np.cross(axis, side), axis):
        before = env.task.sim.tip_pos().copy()
        for _ in range(3):
            env.step(0.4 * direction)
        moved = (env.task.sim.tip_pos() - before) * 1000.0
        assert moved @ direction > 5.0 and moved @ direction > 0.9 * np.linalg.norm(moved)  # 7-8 mm, 0.95-1
    aim = type("Aim", (), {"reset": lambda self, task: None,
                           "act": lambda self, obs, task: np.clip(obs[:3] / 25.0, -0.4, 0.4)})()
    steps = list(episode(env, aim, seed=2))
    assert steps[-1].info["is_success"] and len(steps) < 80
    with pytest.raises(ValueError, match=r"3 values \(the tip displacement's x, y, z \(task_space\)\)"):
        env.step(np.zeros(5))
    with pytest.raises(ConfigError, match="residual and task_space .* choose one"):
        EndoscopeEnv("DE", task_space=True, residual=True)
    with pytest.raises(PolicyError, match=r"acts by cable and insertion commands \(task_space=False\), the task has "
                                          r"task_space=True: build the task with the policy's setting"):
        load_controller("E", env.task)  # same observation, another action: refused before a step


def test_history_observation_is_the_last_four_observations_newest_first():
    plain, stacked = EndoscopeEnv("DE"), EndoscopeEnv("DE", history_obs=True)
    assert stacked.observation_space.shape == (15 * 5,)
    np.testing.assert_array_equal(stacked.observation_space.low[15:30], stacked.observation_space.low[:15])
    seen = [plain.reset(seed=5)[0]]
    oq, _ = stacked.reset(seed=5)
    np.testing.assert_array_equal(oq[:15], seen[0])
    np.testing.assert_array_equal(oq[15:].reshape(4, 15), np.tile(seen[0], (4, 1)))  # nothing happened before
    for a in np.array([[0.3, 0.0, -0.2, 0.1, 0.4], [0.0, 0.4, 0.0, -0.4, 0.4], [-0.1, 0.0, 0.2, 0.0, -0.2]] * 3):
        seen.append(plain.step(a)[0])
        oq, *_ = stacked.step(a)
        np.testing.assert_array_equal(oq[:15], seen[-1])  # the same physics and the paper's observation
        past = [seen[max(len(seen) - 2 - j, 0)] for j in range(4)]
        np.testing.assert_array_equal(oq[15:].reshape(4, 15), past)
    assert np.linalg.norm(seen[-1][:3] - seen[-5][:3]) > 1.0  # the stack spans motion (mm), not four copies
    oq, _ = stacked.reset(seed=6, options={"target_index": int(stacked.task.targets[3])})
    np.testing.assert_array_equal(oq[15:].reshape(4, 15), np.tile(oq[:15], (4, 1)))  # a new episode forgets


def test_target_weights_set_how_often_each_target_is_drawn():
    env = EndoscopeEnv("DE")
    hard = set(env.task.targets[env.task.contact_aided].tolist())
    assert 0.5 < len(hard) / len(env.task.targets) < 0.8  # list A: about two thirds (docs/task.md)

    def share(weight, n=150):
        env.set_target_weights(np.where(env.task.contact_aided, weight, 1.0))
        return np.mean([env.reset(seed=s)[1]["target_index"] in hard for s in range(n)])

    assert share(0.0) == 0.0
    assert 0.1 < share(0.25) < 0.5 < share(1.0) < 0.8
    assert env.task.target_p is None  # equal weights: the paper's uniform draw, unchanged
    with pytest.raises(ValueError, match="target weights"):
        env.set_target_weights(np.zeros(len(env.task.targets)))


def test_bad_actions_and_names():
    env = EndoscopeEnv("DE")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="NaN"):
        env.step(np.array([np.nan, 0, 0, 0, 0]))
    with pytest.raises(ValueError, match="5 values"):
        env.step(np.zeros(3))
    # Out of range is clipped: 10 behaves as 0.4.
    a, b = EndoscopeEnv("SE"), EndoscopeEnv("SE")
    a.reset(seed=0)
    b.reset(seed=0)
    np.testing.assert_array_equal(a.step(np.full(5, 10.0))[0], b.step(np.full(5, 0.4))[0])
    with pytest.raises(ConfigError, match="valid: FE, SE, DE, UE1, UE2"):
        EndoscopeEnv("XX")
    with pytest.raises(ConfigError, match="valid: 'A', 'B'"):
        EndoscopeEnv("DE", target_list="C")
    with pytest.raises(ConfigError, match="camera"):
        EndoscopeEnv("DE", camera="nose")
    with pytest.raises(ValueError, match=r"target 0 is not in target list A \(\d+(, \d+){7}, \.\.\. \(\d+ in all\)\); "
                       "pick one of env.task.targets$"):
        env.reset(seed=0, options={"target_index": 0})  # names a few of the list's ids, not all of them
    with pytest.raises(ConfigError, match="unknown reset option.*target; valid: target_index"):
        env.reset(seed=0, options={"target": int(env.task.targets[0])})  # a misspelt option is not ignored
    with pytest.raises(ConfigError, match="target_index must be a whole number, not '3'"):
        env.reset(seed=0, options={"target_index": "3"})
    with pytest.raises(ConfigError, match="anatomy_index 1 is not one of this environment's 1 stomach"):
        env.reset(seed=0, options={"anatomy_index": 1})  # the built-in stomach is no set of stomachs
    with pytest.raises(gym.error.Error):
        gym.make("mjendo/XE-v0")


def test_instability_truncates_with_a_reason():
    env = EndoscopeEnv("DE")
    env.reset(seed=0)
    env.task.sim.data.qvel[:] = 1e7
    _, _, term, trunc, info = env.step(np.zeros(5))
    assert trunc and not term and "instability" in info
    obs, *_ = env.step(np.zeros(5))  # the env recovered: the next step is fine
    assert np.isfinite(obs).all()


def test_baseline_reaches_free_space_targets_in_fe():
    env = EndoscopeEnv("FE", max_steps=80)
    ctrl = DLSController(env.task)
    free = env.task.targets.tolist()  # FE's list F: points the sweep reached within 3 mm in free space
    reached = [run(env, ctrl, target=t)[0]["is_success"] for t in free[::15][:12]]
    assert sum(reached) >= 3, reached


def test_dm_control_task_matches_the_gym_env():
    # The same start state and actions through both APIs give the same observations and rewards.
    import mujoco

    from mjendo import suite

    gym_env = EndoscopeEnv("DE", force_obs=True)
    dm_env = suite.load("DE", force_obs=True)
    obs, _ = gym_env.reset(seed=5)
    dm_env.reset()
    g, d = gym_env.task, dm_env.task.core
    spec = mujoco.mjtState.mjSTATE_INTEGRATION
    state = np.empty(mujoco.mj_stateSize(g.sim.model, spec))
    mujoco.mj_getState(g.sim.model, g.sim.data, state, spec)
    mujoco.mj_setState(d.sim.model, d.sim.data, state, spec)
    mujoco.mj_forward(d.sim.model, d.sim.data)
    d.set_target(g.target)
    rng = np.random.default_rng(0)
    for _ in range(10):
        a = rng.uniform(-0.4, 0.4, 5)
        obs, r, *_ = gym_env.step(a)
        ts = dm_env.step(a)
        flat = np.concatenate([ts.observation[k] for k in ts.observation])
        np.testing.assert_allclose(flat, obs, rtol=1e-5, atol=1e-5)
        assert ts.reward == pytest.approx(r)
    assert dm_env.control_timestep() == pytest.approx(0.1)
    assert ts.reward == pytest.approx(-dm_env.physics.distance_mm())


def test_render_external_and_tip_cameras():
    env = EndoscopeEnv("DE", render_mode="rgb_array", camera="both", width=160, height=120)
    env.reset(seed=0)
    frame = env.render()
    env.close()
    assert frame.shape == (120, 320, 3)
    assert frame[:, :160].std() > 5 and frame[:, 160:].std() > 1  # neither view is blank


def test_constructing_an_env_prints_nothing(capfd):
    # meshio printed an empty line for every mesh it read while guessing the file format.
    EndoscopeEnv("DE")
    assert capfd.readouterr().out == ""


@pytest.mark.parametrize("name", ["FE", "SE", "DE", "UE1", "UE2"])
def test_dm_control_specs_before_and_after_reset(name):
    # dm_env users ask for specs first; the force blocks read a contact before any reset.
    from mjendo import suite

    env = suite.load(name, force_obs=True)
    before = env.observation_spec()
    assert list(before) == ["ee_to_target", "ee_velocity", "cable_lengths", "previous_axial_action", "contact",
                            "force"]
    assert [s.shape for s in before.values()] == [(3,), (3,), (4,), (1,), (1,), (3,)]
    ts = env.reset()
    assert ts.first() and ts.reward is None and ts.discount is None
    for key, spec in env.observation_spec().items():
        assert spec.shape == before[key].shape and spec.dtype == np.float64
        spec.validate(ts.observation[key])
    ts = env.step(np.zeros(5))
    assert ts.mid() and ts.discount == 1.0 and np.isfinite(ts.reward)


@pytest.mark.parametrize("name", ["FE", "SE", "DE", "UE1", "UE2"])
def test_dm_control_specs_force_blind_and_discounts(name):
    from mjendo import suite

    env = suite.load(name, force_obs=False)
    assert list(env.observation_spec()) == ["ee_to_target", "ee_velocity", "cable_lengths", "previous_axial_action"]
    act = env.action_spec()
    assert act.shape == (5,) and act.dtype == np.float64 and act.minimum.min() == -0.4 and act.maximum.max() == 0.4
    env.reset()
    ts = env.step(np.zeros(5))
    assert ts.discount == 1.0 and ts.mid()


def test_dm_control_discount_is_zero_on_success_and_exit_one_on_time_limit():
    from mjendo import suite

    env = suite.load("SE", force_obs=True, max_steps=200)
    env.reset()
    while True:  # withdraw through the cardia: terminal, absorbing
        ts = env.step(np.array([0, 0, 0, 0, -0.4]))
        if ts.last():
            break
    assert ts.discount == 0.0 and env.task.core.tip_x_mm() < 15.0
    env = suite.load("SE", force_obs=True, max_steps=3)
    env.reset()
    steps = [env.step(np.zeros(5)) for _ in range(3)]
    assert steps[-1].last() and steps[-1].discount == 1.0  # truncation: bootstrap


def test_force_penalty_costs_reward_in_proportion_to_the_force():
    def press(penalty):
        env = EndoscopeEnv("SE", force_penalty=penalty)
        env.reset(seed=0)
        for _ in range(60):
            _, r, term, _, info = env.step(np.array([0, 0, 0, 0, 0.4]))
            assert not term, "the episode ended before the scope pressed the wall"
            if np.linalg.norm(info["force_N"]) > 0.2:
                return r, info
        raise AssertionError("never pressed the wall")

    r0, i0 = press(0.0)
    r2, i2 = press(2.0)
    f = np.linalg.norm(i2["force_N"])
    assert i0["reward_force"] == 0.0 and i2["reward_force"] == pytest.approx(-2.0 * f)
    assert r2 == pytest.approx(r0 - 2.0 * f)


def test_randomize_phase_draws_the_load_phase_and_can_be_switched_off():
    def start_times(randomize):
        env = EndoscopeEnv("DE", randomize_phase=randomize)
        cycle = 2 * env.task.sim.half_period
        times = set()
        for seed in range(6):
            env.reset(seed=seed)
            times.add(round(env.task.sim.time % cycle, 3))
        return times

    assert len(start_times(True)) >= 4
    assert len(start_times(False)) == 1


def test_target_list_override_uses_the_other_list():
    st_a = EndoscopeEnv("DE")
    st_b = EndoscopeEnv("DE", target_list="B")
    a = {st_a.reset(seed=s)[1]["target_index"] for s in range(30)}
    b = {st_b.reset(seed=s)[1]["target_index"] for s in range(30)}
    lists = targets.load().lists
    assert a <= set(lists["A"]) and b <= set(lists["B"])
    assert not (a & b)
    assert EndoscopeEnv("FE").task.target_list == "F" and EndoscopeEnv("FE", version=0).task.target_list == "A"
    assert EndoscopeEnv("UE1").task.target_list == "B" and EndoscopeEnv("UE1", target_list="A").task.target_list == "A"


BAD_TASK_ARGS = [
    ({"force_penalty": float("nan")}, "force_penalty must be a finite number"),
    ({"force_penalty": float("inf")}, "force_penalty must be a finite number"),
    ({"force_penalty": -1.0}, "force_penalty must be a finite number >= 0"),
    ({"force_ref_n": 0.0}, "force_ref_n must be a finite number > 0"),
    ({"contact_time_constant_s": 0.0}, "contact_time_constant_s must be a finite number > 0"),
    ({"contact_time_constant_s": 40.0}, "contact_time_constant_s is in seconds: at most 1"),
    ({"distance_weight": -1.0}, "distance_weight must be a finite number >= 0"),
    ({"cable_mm_per_unit": float("nan")}, "cable_mm_per_unit must be a finite number"),
    ({"insertion_mm_per_unit": float("inf")}, "insertion_mm_per_unit must be a finite number"),
    ({"force_obs": "false"}, "force_obs must be True or False"),
    ({"scope_obs": 1}, "scope_obs must be True or False"),
    ({"time_obs": "yes"}, "time_obs must be True or False"),
    ({"randomize_phase": 1}, "randomize_phase must be True or False"),
    ({"max_steps": 1.7}, "max_steps must be a whole number"),
    ({"max_steps": 0}, "max_steps must be a whole number >= 1"),
    ({"width": 0}, "width must be a whole number of pixels"),
    ({"height": 100000}, "height must be a whole number of pixels"),
    ({"control_period_s": 0.03}, "not a multiple of the fast timestep 0.02 s; use e.g. 0.04"),
    ({"timestep_s": 0.03}, "not a multiple of the fast timestep 0.03 s; use e.g. 0.09"),
    ({"timestep_s": 0.0}, "timestep_s must be a finite number > 0"),
    ({"timestep_s": 0.1}, "timestep_s must be at most 0.05 s"),
    ({"version": 7}, "unknown task version 7"),
    ({"target_list": "C"}, "unknown target_list 'C'"),
    ({"cable_mm": 2.0}, "unknown task argument"),
]


@pytest.mark.parametrize("kwargs,message", BAD_TASK_ARGS)
def test_bad_task_arguments_are_refused_at_construction(kwargs, message):
    with pytest.raises(ConfigError, match=message):
        EndoscopeEnv("DE", **kwargs)


def test_another_physics_step_keeps_the_control_period_and_the_scope_converges():
    # The same open-loop commands in free space at the fast stomach's 20 ms and at 10 ms: each control step still
    # lasts 0.1 s, and the tip's path differs by about a millimetre (the scope alone converges in the step).
    actions = np.clip(np.random.default_rng(0).normal(0, 0.25, (30, 5)), -0.4, 0.4)
    actions[:, 4] = np.abs(actions[:, 4]) + 0.15
    paths = []
    for dt in (None, 0.01):
        env = EndoscopeEnv("FE", fidelity="fast-coarse", timestep_s=dt, randomize_phase=False)
        assert env.task.sim.model.opt.timestep == (dt or 0.02) and env.task.control_dt == pytest.approx(0.1)
        env.reset(seed=0)
        t0 = env.task.sim.data.time
        tips = []
        for a in actions:
            env.step(a)
            tips.append(env.task.sim.tip_pos())
        assert env.task.sim.data.time - t0 == pytest.approx(3.0)
        paths.append(np.array(tips))
    gap_mm = 1000 * np.linalg.norm(paths[0] - paths[1], axis=1)
    travel_mm = 1000 * np.linalg.norm(paths[0][-1] - paths[0][0])
    assert travel_mm > 30 and gap_mm.mean() < 1.5 and gap_mm.max() < 4.0


def test_a_longer_contact_time_constant_is_a_softer_contact():
    # The same push into the wall in SE: with the contacts' and anchors' time constant at 40 ms instead of the scene's
    # 20 and 10 ms, the tip sinks deeper into the wall and presses it less hard.
    def push(tc):
        env = EndoscopeEnv("SE", fidelity="fast-coarse", contact_time_constant_s=tc)
        env.reset(seed=0)
        deepest, peak = 0.0, 0.0
        for _ in range(40):
            info = env.step(np.array([0.4, 0, 0, 0, 0.4]))[4]
            data = env.task.sim.data
            deepest = min([deepest, *data.contact.dist[:data.ncon]])
            peak = max(peak, float(np.linalg.norm(info["force_N"])))
        return env.task.sim.model, 1000 * deepest, peak

    scene, scene_mm, scene_n = push(None)
    soft, soft_mm, soft_n = push(0.04)
    assert scene.geom_solref[:, 0].max() == 0.02 and scene.eq_solref[:, 0].min() == 0.01
    assert (soft.geom_solref[:, 0] == 0.04).all() and (soft.eq_solref[:, 0] == 0.04).all()
    assert scene_mm < -1.0 and soft_mm < scene_mm - 0.3  # about 2.1 and 2.6 mm into the wall
    assert 0.1 < soft_n < 0.9 * scene_n  # about 0.23 against 0.31 N


def test_bad_control_never_reaches_mujoco_silently():
    # MuJoCo zeroes a NaN control with only a BADCTRL warning; the simulator treats it as divergence.
    env = EndoscopeEnv("DE")
    env.reset(seed=0)
    env.task.sim.data.ctrl[0] = np.nan
    import mujoco

    mujoco.mj_step(env.task.sim.model, env.task.sim.data)
    from mjendo.sim import InstabilityError

    with pytest.raises(InstabilityError, match="control"):
        env.task.sim.check()


def test_env_copies_and_pickles_after_rendering():
    import copy
    import pickle

    env = EndoscopeEnv("DE", render_mode="rgb_array", width=64, height=48)
    env.reset(seed=0)
    frame = env.render()
    twin = copy.deepcopy(env)
    back = pickle.loads(pickle.dumps(env))
    np.testing.assert_array_equal(twin.step(np.zeros(5))[0], env.step(np.zeros(5))[0])  # same state, copied
    for e in (twin, back, env):
        assert e.render().shape == frame.shape  # a new renderer is made on demand
        e.close()


def test_observations_have_physical_bounds_and_check_env_is_quiet(recwarn):
    env = EndoscopeEnv("DE")
    space = env.observation_space
    assert np.isfinite(space.low).all() and np.isfinite(space.high).all()
    assert space.high[0] == 1000.0 and space.high[3] == 5000.0 and space.high[12] == 100.0
    check_env(env, skip_render_check=True)
    assert not [w for w in recwarn if "mjendo" in str(w.filename) or "Box" in str(w.message)
                or "bound" in str(w.message).lower()], [str(w.message) for w in recwarn]
    env.task.sim.data.qvel[:] = 0.0
    obs = env.task.observation(np.array([5.0, 0.0, 0.0]))  # 5 m away: clipped to the 1 m bound
    assert obs[0] == 1000.0 and space.contains(obs)
