"""The model of record behaves like a damped elastic wall: held presses settle, episodes start settled."""

import subprocess
import sys

import mujoco
import numpy as np
import pytest

from mjendo import fidelity
from mjendo.config import FIDELITIES, ConfigError, Material, Randomization
from mjendo.sim import Simulator
from mjendo.task import NavigationTask

# End-on into the greater curvature, and the bent tip driven into a side wall.
# Presses the feeder holds at their depth. The end-on 155 mm press saturates the 3 N feeder of task version 1
# (146 of 155 mm): under a force-limited push the tip slides on along the wall (full: 2.4 mm/s after 4 s).
HELD = [fidelity.PRESSES[0], fidelity.PRESSES[2]]


# The full stomach with the version-1 chain (armature 1e-3 on its hinges) creeps along the wall at about
# 1 mm/s for seconds under a held press (end-on 140 mm, tip/wall mm/s after 2 / 3 / 4 s: 1.08/1.80,
# 0.49/0.82, 0.19/0.31; bent +x: 0.15/0.18, 0.93/1.19 after 4 s, 0.48/0.56 after 6 s); the fast stomach,
# which trains and evaluates, comes to rest (docs/physics.md "Known limits"). Strict: it fails once fixed.
FULL_CREEPS = pytest.mark.xfail(strict=True, reason="full stomach creeps ~1 mm/s under a held v1 press")


@pytest.mark.parametrize("fid", [pytest.param(f, marks=FULL_CREEPS) if f == "full" else f for f in FIDELITIES])
def test_a_held_press_comes_to_rest(fid):
    # An under-converged solve (full at tolerance 1e-4: tip 24 mm/s) or frictional creep
    # (scope friction 1.0: fast tip 4-6 mm/s for seconds) keeps the scope moving.
    sim = Simulator("SE", fid)
    for press in HELD:
        tip, wall = fidelity.hold_speeds(sim, press, hold_s=2.0)
        assert sim.contact().active, f"{press.name} lost the wall"
        assert tip < 1.0 and wall < 1.0, f"{fid} {press.name}: tip {tip:.2f} mm/s, wall {wall:.2f} mm/s"


def test_the_speed_benchmark_sweeps_the_scope_along_the_wall():
    # make bench's physics figure is only meaningful if its sweep is contact-rich.
    sim = Simulator("DE", "fast")
    rate, counts = fidelity.sweep(sim, 1.0, record_counts=True)
    iters, contacts = counts.T
    assert rate > 0 and len(iters) == round(1.0 / sim.model.opt.timestep)
    # Measured: the scope touches the wall in 80 % of the sweep's steps (6 contacts, median; the sweep
    # restarts from insertion 0, so it leaves the wall for a moment), with either solver.
    assert np.mean(contacts >= 2) >= 0.6 and np.median(contacts) >= 4
    assert 1 <= iters.min() and iters.max() <= sim.model.opt.iterations


def test_a_press_pushes_back_harder_the_deeper_it_goes():
    sim = Simulator("SE", "fast")
    shallow, deep = (fidelity.press_force(sim, p) for p in fidelity.PRESSES[:2])
    assert 0.2 < shallow < deep < 10.0


def test_contacts_use_the_papers_friction():
    # MuJoCo combines a contact's two friction coefficients by their maximum.
    for fid in FIDELITIES:
        sim = Simulator("SE", fid)
        m = sim.model
        colliding = sim.scope_geom & ((m.geom_contype | m.geom_conaffinity) > 0)
        assert colliding.sum() == 16  # the tube's links
        scope = m.geom_friction[colliding, 0]
        assert np.allclose(np.maximum(scope, m.flex_friction[0, 0]), 0.1)


def _vertices(task, state):
    m, d = task.sim.model, task.sim.data
    mujoco.mj_setState(m, d, state, mujoco.mjtState.mjSTATE_INTEGRATION)
    mujoco.mj_forward(m, d)
    return task.sim.vertices()


def test_episodes_start_settled_at_the_drawn_load_phase():
    task = NavigationTask(env="UE2", fidelity="fast")
    starts = task._starts
    cycle = 2 * task.sim.half_period
    times = []
    for seed in range(6):
        task.reset(np.random.default_rng(seed))
        times.append(task.sim.time)
    assert len(set(np.round(np.mod(times, cycle), 3))) >= 4, "the load phase is not drawn"
    # Run on from a drawn start with the scope idle: the wall follows the periodic steady
    # state, i.e. it reaches the snapshot recorded one second later in the cycle, with no
    # transient. (Starting from the stomach settled under +f0 misses it by millimetres.)
    task.reset(np.random.default_rng(3))
    t0 = task.sim.time
    task.sim.step(int(round(1.0 / task.sim.model.opt.timestep)))
    now = task.sim.vertices()
    later = int(np.argmin([abs(((t - t0 - 1.0 + cycle / 2) % cycle) - cycle / 2)
                           for t in (s[0] for s in starts)]))
    ref = _vertices(task, starts[later])
    # Within 1.5 mm of motions up to 90 mm: the recorded cycle follows one settling cycle, so a
    # snapshot that wraps round to its start is periodic to about 1 %.
    assert np.abs(now - ref).max() < 1.5e-3
    # ... while the wall really moves over that second.
    task.reset(np.random.default_rng(3))
    assert np.abs(task.sim.vertices() - ref).max() > 3e-3


def test_static_stomach_has_one_start_state():
    task = NavigationTask(env="SE", fidelity="fast")
    assert len(task._starts) == 1


def test_full_wall_motion_does_not_depend_on_the_timestep():  # two full-stomach load cycles, 36-50 s
    # Without the viscera's drag the stomach's slowest mode rang and the 10 ms step's numerical
    # damping hid it: target motion 14.5 mm at 10 ms, 17.8 at 5 ms (DE median). With it: 11.1, ~11.4.
    from dataclasses import replace

    targets = fidelity.all_targets()
    coarse = fidelity.target_motion(Simulator("DE", "full"), targets)
    fine = fidelity.target_motion(fidelity.simulator("DE", replace(FIDELITIES["full"], timestep_s=0.005)), targets)
    ratio = np.median(coarse) / np.median(fine)
    assert 0.94 < ratio <= 1.02, f"median target motion at 10 ms / 5 ms = {ratio:.3f}"
    assert 0.94 < coarse.max() / fine.max() <= 1.02


def test_the_wall_is_dragged_in_proportion_to_its_mass():
    # Rayleigh alpha: a passive damper per flex dof, damping = drag_per_s x the dof's mass, that
    # no ctrl can drive (gain 0).
    for fid in FIDELITIES:
        sim = Simulator("DE", fid)
        m = sim.model
        drag = [a for a in range(m.nu) if mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a).startswith("drag_")]
        dofs = m.jnt_dofadr[m.actuator_trnid[drag, 0]]
        flex_bodies = set(m.flex_vertbodyid) | set(m.flex_nodebodyid)
        moving = [d for d in range(m.nv) if m.dof_bodyid[d] in flex_bodies and m.body_mass[m.dof_bodyid[d]] > 0]
        assert sorted(dofs) == moving
        expected = Material().drag_per_s * m.body_mass[m.dof_bodyid[dofs]]
        np.testing.assert_allclose(m.actuator_damping[drag], expected, rtol=1e-5)  # XML: 6 digits
        sim.step(10)
        spec = mujoco.mjtState.mjSTATE_INTEGRATION
        state = np.empty(mujoco.mj_stateSize(m, spec))
        mujoco.mj_getState(m, sim.data, state, spec)
        sim.step(5)
        free = sim.data.qpos.copy()
        mujoco.mj_setState(m, sim.data, state, spec)
        sim.data.ctrl[drag] = 1.0
        sim.step(5)
        np.testing.assert_array_equal(sim.data.qpos, free, err_msg=f"{fid}: ctrl drives the drag")


def test_the_compliant_fast_stomach_puts_the_tip_where_the_fem_wall_does():
    # The motion that reaches list A's contact-aided point 2287 in the static fast stomach (demonstrator
    # 67: bend, insert at full speed, slide along the greater curvature), replayed in each stomach.
    # Measured over its 80 steps: fast 4.6 mm from the full stomach's tip path on average, fast-compliant
    # 1.3 (over all 32 of list A's demonstrators 2.3 and 1.3: `python -m mjendo.fidelity tracks`).
    paths = {f: fidelity.tip_tracks(f, demos=[67])[0][0] for f in ("fast", "fast-compliant", "full")}
    off = {f: np.linalg.norm(paths[f] - paths["full"], axis=1).mean() for f in ("fast", "fast-compliant")}
    assert off["fast-compliant"] < 2.0 < 3.5 < off["fast"], off
    # The two fast stomachs differ in the contact's impedance alone.
    a, b = (Simulator("SE", f).model for f in ("fast", "fast-compliant"))
    assert a.nv == b.nv and np.array_equal(a.flex_stiffness, b.flex_stiffness)
    assert np.array_equal(a.geom_friction, b.geom_friction) and a.opt.timestep == b.opt.timestep
    assert b.flex_solimp[0, 0] < a.flex_solimp[0, 0]


def test_tracks_of_a_later_version_replay_its_own_demonstrators():
    # Version 2's map recorded demonstrators version 1's does not race (indices from 180 on), at its 10 ms step:
    # replayed in version 2's fast stomach one reaches the point it was recorded for.
    from mjendo import targets

    d, point = next((d, i) for d, i in targets.static_demos("A", targets.targets_file(2)) if d >= targets.V1_DEMOS)
    tips, arrivals = fidelity.tip_tracks("fast", demos=[d], version=2)
    assert arrivals[d, point] is not None and tips.shape == (1, targets.TRIAL_STEPS, 3)


def test_a_policys_actions_replayed_open_loop_retrace_its_trial():
    # policy-tracks compares stomachs under a policy's own motions by replaying its closed-loop actions; that
    # rests on a replay retracing the trial it came from, and on the figures seeing a changed stomach.
    spec = "models/policies/variants/E-paired"
    closed = fidelity.policy_rollouts(spec, "SE", "fast", 1)
    k = closed["steps"][0]
    assert 0 < k < 80 and np.linalg.norm(closed["tip"][0, k - 1] - closed["target"][0, k - 1]) < 3.0  # trial 0 arrives
    same = fidelity.rollout_figures(closed, fidelity.policy_rollouts(spec, "SE", "fast", 1, actions=closed["action"]))
    assert same["tip_mean_mm"] == 0.0 and same["force_abs_diff_mean_n"] == 0.0 and same["arrive_in_one_only"] == 0
    softer = fidelity.policy_rollouts(spec, "SE", "fast", 1, actions=closed["action"], solimp=(0.1, 0.99, 0.01))
    moved = fidelity.rollout_figures(closed, softer)
    assert moved["steps"] == k and moved["tip_mean_mm"] > 0.0


def test_the_give_protocol_measures_the_give_a_candidate_adds():
    # target_give's gain is what calibrates Randomization.target_give_mm_per_n against the FEM wall: a drawn give
    # of 1 mm/N must read as about 1 mm/N more than the wall's own, and a wall moves only once it is touched.
    only = {name: None for name in Randomization.RANGES} | {"load_tilt_deg": 0.0, "force_noise_n": 0.0,
                                                           "target_noise_mm": 0.0, "settle_s": 0.0}
    own = fidelity.target_give("E", "fast-coarse", targets=2)
    more = fidelity.target_give("E", "fast-coarse", targets=2, randomization=only | {"target_give_mm_per_n": (1, 1)})
    assert own["trials"] == more["trials"] == 2 and 0 <= own["reached"] <= 2
    assert 0.2 < own["gain_mm_per_n"] < 2.0 and 0.0 < own["moved_median_mm"] <= own["moved_p90_mm"]
    assert more["gain_mm_per_n"] - own["gain_mm_per_n"] == pytest.approx(1.0, abs=0.25)
    assert more["moved_median_mm"] > own["moved_median_mm"]


def test_policy_tracks_refuse_a_cache_of_other_trials(tmp_path):
    cache = tmp_path / "ref.npz"
    other = "models/policies/variants/D-paired in SE, full stomach"
    np.savez_compressed(cache, steps=np.array([3]), made_by=np.array(other))
    with pytest.raises(ConfigError, match="does not hold the trials of models/policies/variants/E-paired in SE"):
        fidelity.policy_track_comparison("models/policies/variants/E-paired", "SE", "fast", cache=cache)
    res = subprocess.run([sys.executable, "-m", "mjendo.fidelity", "policy-tracks", "--policy", "runs/E/nothing"],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and "unknown policy 'runs/E/nothing'" in res.stderr and "Traceback" not in res.stderr


def test_the_one_cell_stomach_is_calibrated_as_the_fast_one():
    # fast-coarse (8 trilinear nodes) drives its load with its own gains: its median target motion over a load
    # cycle is the fast stomach's (both the full stomach's 3.14 mm in DE), although its 8 nodes move the
    # targets as one block (larger maximum); its presses push back as hard as the fast stomach's within 2x.
    targets = fidelity.all_targets()
    coarse, fast = (fidelity.target_motion(Simulator("DE", f), targets) for f in ("fast-coarse", "fast"))
    assert np.median(coarse) == pytest.approx(np.median(fast), rel=0.03)
    assert np.median(coarse) > 2.5e-3  # the wall does move: 3 mm, not a block held still
    sims = {f: Simulator("SE", f) for f in ("fast-coarse", "fast")}
    for press in fidelity.PRESSES[::2]:
        a, b = (fidelity.press_force(sims[f], press) for f in ("fast-coarse", "fast"))
        assert 0.5 < a / b < 2.0, f"{press.name}: fast-coarse {a:.3f} N, fast {b:.3f} N"


def test_the_spike_protocol_drives_any_fast_stomach_into_the_wall_and_refuses_one_a_version_lacks():
    # Two bang-bang episodes that insert on most steps reach the wall of the one-cell stomach: the scope pushes
    # on it with tenths of a newton (the 3 N feeder's share), and every step is counted.
    row = fidelity.spikes(1, episodes=2, push=0.9, fidelity="fast-coarse")
    assert row["fidelity"] == "fast-coarse" and row["steps"] > 100
    assert 0.2 < row["max_N"] < 10.0 and row["over_10N"] == 0.0
    res = subprocess.run([sys.executable, "-m", "mjendo.fidelity", "spikes", "--versions", "0", "--fidelity",
                          "fast-coarse", "--episodes", "1"], capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and "exists from task version 1" in res.stderr and "Traceback" not in res.stderr
