"""The MuJoCo Warp backend on Warp's CPU device: the same MDP as the CPU task, checked where paths do not diverge.

Contact-rich trajectories of the two backends diverge (float32, different flex-collision contact sets), so
step-by-step agreement is asserted before contact; with contact, quantities that do not depend on the path
are compared (docs/backends.md).
"""

import sys

import mujoco
import numpy as np
import pytest

pytest.importorskip("mujoco_warp", reason="the batched backend needs the optional extra mjendo[warp]")
# MuJoCo Warp on its CPU device: kernels compile on first use, so one test worker runs them all.
pytestmark = [pytest.mark.integration, pytest.mark.xdist_group("warp")]

from mjendo.batch import BatchedNavigation, uniform, vec_env  # noqa: E402
from mjendo.config import ConfigError, task_config  # noqa: E402
from mjendo.envs import EndoscopeEnv  # noqa: E402


def twins(batch, env_name, fidelity="fast"):
    """CPU environments in exactly the start state (phase snapshot and target) each world drew."""
    envs = []
    for i in range(batch.n):
        e = EndoscopeEnv(env_name, fidelity=fidelity, force_obs=True)
        e.reset(seed=0)
        t = e.task
        mujoco.mj_setState(t.sim.model, t.sim.data, t._starts[int(batch.phase[i])],
                           mujoco.mjtState.mjSTATE_INTEGRATION)
        mujoco.mj_forward(t.sim.model, t.sim.data)
        t.contact = t.sim.contact()
        t.set_target(int(batch.target[i]))
        envs.append(e)
    return envs


SOLVE_TO_CONVERGENCE = 10_000  # iteration cap for single-state comparisons (the presets stop at 1,000)


def load_cpu_state(batch, i, d):
    """Copy a CPU MjData's state into world ``i`` (the caller runs Warp's forward afterwards)."""
    for name, v in (("qpos", d.qpos), ("qvel", d.qvel), ("warmstart", d.qacc_warmstart), ("ctrl", d.ctrl)):
        getattr(batch, name)[i] = batch._torch.as_tensor(v, dtype=getattr(batch, name).dtype)
    batch.time[i] = d.time


# float32 physics against float64: tip and target positions agree to hundredths of a millimetre over a few
# control steps, velocities to hundredths of a mm/s; cable lengths to microns.
POS_MM, VEL_MM_S = 0.05, 0.1


@pytest.mark.parametrize("env_name,insertion,steps", [("FE", 0.1, 8), ("DE", -0.05, 3)])
def test_before_contact_worlds_track_the_cpu_task_step_by_step(env_name, insertion, steps):
    batch = BatchedNavigation(2, env=env_name, fidelity="fast", device="cpu", seed=3)
    obs = batch.reset().numpy()
    envs = twins(batch, env_name)
    np.testing.assert_allclose(obs[:, :11], np.array([e.task.observation() for e in envs])[:, :11], atol=1e-3)
    rng = np.random.default_rng(0)
    for _ in range(steps):
        a = rng.uniform(-0.1, 0.1, (2, 5)) if env_name == "FE" else np.zeros((2, 5))
        a[:, 4] = insertion
        r = batch.step(a)
        cpu = [e.step(a[i]) for i, e in enumerate(envs)]
        assert not r.info["contact"].any() and not any(c[4]["contact"] for c in cpu)
        o, oc = r.obs.numpy(), np.array([c[0] for c in cpu])
        assert np.abs(o[:, 0:3] - oc[:, 0:3]).max() < POS_MM  # tip to target: the wall moves alike under the load
        assert np.abs(o[:, 3:6] - oc[:, 3:6]).max() < VEL_MM_S
        assert np.abs(o[:, 6:10] - oc[:, 6:10]).max() < 1e-3
        np.testing.assert_allclose(r.reward.numpy(), [c[1] for c in cpu], atol=POS_MM)


@pytest.mark.parametrize("fidelity", ["fast", pytest.param("full", marks=pytest.mark.slow)])
def test_contact_indicator_and_force_agree_for_the_same_state(fidelity):
    # Press the straight scope into the far wall on the CPU, copy those states into two worlds, and read the
    # resultant contact force both ways: Warp's contact data + constraint forces vs mj_contactForce.
    env = EndoscopeEnv("SE", fidelity=fidelity, force_obs=True)
    env.reset(seed=0)
    m, d = env.task.sim.model, env.task.sim.data
    states = []
    for k in range(60):
        _, _, _, _, info = env.step(np.array([0.1 if k > 25 else 0.0, 0, 0, 0, 0.4]))
        if np.linalg.norm(info["force_N"]) > 0.3 and k % 3 == 0:
            states.append((d.qpos.copy(), d.qvel.copy(), d.time, d.qacc_warmstart.copy(), d.ctrl.copy()))
        if len(states) == 2:
            break
    batch = BatchedNavigation(2, env="SE", fidelity=fidelity, device="cpu")
    batch.reset()
    # These are states of a hard insertion: the pyramidal contact solve of the full stomach needs up to ~3,000
    # iterations there (measured: 5.9-7.4 N across tolerances at the preset's cap of 1,000, 6.77 N converged), so
    # both solvers get a cap that lets them converge: the test compares force read-outs, not unconverged solves.
    m.opt.iterations = batch.mw.opt.iterations = SOLVE_TO_CONVERGENCE
    cpu = []
    for i, (qp, qv, t, ws, ctrl) in enumerate(states):
        d.qpos[:], d.qvel[:], d.qacc_warmstart[:], d.ctrl[:], d.time = qp, qv, ws, ctrl, t
        load_cpu_state(batch, i, d)
        mujoco.mj_forward(m, d)
        assert d.solver_niter[0] < SOLVE_TO_CONVERGENCE, "the CPU solve did not converge"
        cpu.append(env.task.sim.contact().force)
    batch._mjw.forward(batch.mw, batch.d)
    batch._read_contact()
    assert batch.contact.all()
    for i, f in enumerate(cpu):
        fw = batch.force[i].numpy()
        # The normal push (the wall's main reaction) agrees within 10 %; the small lateral parts depend on which
        # of the near-contacts each collision pipeline keeps. Fast without mjendo.warp_patch: 0.66 vs 7.5 N (the
        # constraint solve saw no scope behind the contact).
        assert np.linalg.norm(fw) == pytest.approx(np.linalg.norm(f), rel=0.10)
        axis = f / np.linalg.norm(f)
        assert fw @ axis == pytest.approx(np.linalg.norm(f), rel=0.10)
    obs = batch.observation().numpy()
    assert (obs[:, 11] == 1.0).all() and np.allclose(obs[:, 12:15], batch.force.numpy(), atol=1e-5)


def test_the_warp_patch_refuses_a_mujoco_warp_it_was_not_written_for(monkeypatch):
    # The whole-chain patch substitutes exact text in mujoco_warp's kernel source; another release must get a
    # clear error naming the version, not a silently unpatched (wrong) contact Jacobian.
    from mujoco_warp._src import constraint

    from mjendo import warp_patch

    monkeypatch.setattr(warp_patch, "_APPLIED", False)
    monkeypatch.setattr(warp_patch.inspect, "getsource", lambda obj: "def _efc_contact_init_flex():\n  pass\n")
    before = constraint._efc_contact_init_flex
    with pytest.raises(ConfigError, match="mujoco-warp==3.17.0"):
        warp_patch.apply()
    assert constraint._efc_contact_init_flex is before


def test_the_implicit_solve_stops_once_every_world_converged_with_the_same_accelerations(monkeypatch):
    # Off CUDA graphs MuJoCo Warp ran all opt.iterations (1,000) PCG iterations of its implicit solve per step;
    # mjendo.warp_patch stops once no world is still solving. The skipped iterations must change nothing.
    import warp as wp
    from mujoco_warp._src import derivative

    from mjendo import warp_patch

    batch = BatchedNavigation(2, env="DE", device="cpu")
    batch.reset()
    batch._mjw.forward(batch.mw, batch.d)
    as_installed = warp_patch.INSTALLED["eff_solve"]
    precs, prec = [], derivative.eff_prec  # one preconditioner call per PCG iteration, and one to start
    monkeypatch.setattr(derivative, "eff_prec", lambda *a, **k: (precs.append(1), prec(*a, **k))[1])
    qacc, iterations = [], []
    for solve in (derivative.eff_solve, as_installed):
        precs.clear()
        out = wp.zeros_like(batch.d.qacc_smooth)
        solve(batch.mw, batch.d, out)
        qacc.append(out.numpy())
        iterations.append(len(precs) - 1)
    assert iterations[1] == batch.mw.opt.iterations == 1000 and 0 < iterations[0] < 100, iterations
    np.testing.assert_array_equal(qacc[0], qacc[1])


def test_worlds_reset_themselves_with_their_own_seeds():
    # Seeds per world: the same batch seed gives the same draws; world i of two batches of different size too.
    a = BatchedNavigation(2, env="FE", device="cpu", seed=7)
    b = BatchedNavigation(3, env="FE", device="cpu", seed=7)
    np.testing.assert_array_equal(a.reset().numpy(), b.reset().numpy()[:2])
    assert (a.target == b.target[:2]).all()
    # A world whose episode ends (time limit here) starts a new one at once: step count 0, a fresh target draw.
    short = BatchedNavigation(2, task_config(env="FE", max_steps=2), device="cpu", seed=1)
    short.reset()
    first = short.target.clone()
    short.step(np.zeros((2, 5)))
    r = short.step(np.zeros((2, 5)))
    assert r.truncated.all() and not r.terminated.any()
    assert (short.steps == 0).all() and (short.episodes == 2).all()
    draws = uniform(short.world_seed, short.episodes - 1, 2)
    expected = short.targets[(draws * len(short.targets)).long()]
    assert (short.target == expected).all() and first.shape == short.target.shape
    assert np.isfinite(r.info["final_obs"].numpy()).all()


def test_a_restarted_world_observes_what_a_forward_pass_and_the_cpu_task_give():
    # Restarts take their first observation from tables the CPU task's reset computed per start snapshot, not
    # from a forward pass of every world (which cost as much as a physics step): the same numbers.
    batch = BatchedNavigation(2, task_config(env="DE", max_steps=1, force_obs=True), device="cpu", seed=5)
    batch.reset()
    r = batch.step(np.tile([0, 0, 0, 0, 0.2], (2, 1)))
    assert r.truncated.all() and (batch.steps == 0).all()  # every world restarted within the step
    restarted = r.obs.numpy()
    cpu = np.array([e.task.observation() for e in twins(batch, "DE")])
    np.testing.assert_allclose(restarted, cpu, atol=1e-4)
    batch._mjw.forward(batch.mw, batch.d)
    batch._read_contact()
    warp = batch.observation().numpy()
    assert np.abs(warp[:, 0:3] - restarted[:, 0:3]).max() < POS_MM
    assert np.abs(warp[:, 3:6] - restarted[:, 3:6]).max() < VEL_MM_S
    assert np.abs(warp[:, 6:] - restarted[:, 6:]).max() < 1e-3


def test_counter_based_draws_are_uniform_and_independent():
    import torch

    seeds = torch.arange(20000, dtype=torch.int64)
    u = uniform(seeds, torch.zeros_like(seeds), 1)
    v = uniform(seeds, torch.ones_like(seeds), 1)
    assert 0.0 <= u.min() and u.max() < 1.0
    assert abs(float(u.mean()) - 0.5) < 0.01 and abs(float(u.std()) - 12 ** -0.5) < 0.01
    assert abs(float(np.corrcoef(u.numpy(), v.numpy())[0, 1])) < 0.03


@pytest.mark.slow  # make train BACKEND=warp (below) trains SB3 on the batched env in the default run
def test_sb3_trains_on_the_batched_env():
    from stable_baselines3 import PPO

    venv = vec_env(2, task_config(env="FE", max_steps=8), device="cpu", seed=0)
    model = PPO("MlpPolicy", venv, n_steps=8, batch_size=16, n_epochs=1, device="cpu", seed=0)
    model.learn(32)
    assert model.num_timesteps == 32 and len(model.ep_info_buffer) >= 2  # episodes ended and were logged
    obs = venv.reset()
    assert obs.shape == (2, 15) and obs.dtype == np.float32 and venv.observation_space.contains(obs[0])


def test_make_train_backend_warp_writes_a_policy_the_cpu_env_runs(tmp_path):
    import yaml

    from mjendo.paths import TRAINING_CONFIG
    from mjendo.policies import PPOController
    from mjendo.train import train

    raw = yaml.safe_load(TRAINING_CONFIG.read_text())
    raw["defaults"].update(checkpoint_every=32, eval_every=10**6)
    raw["defaults"]["batched"] = {"n_envs": 2, "total_timesteps": 64,
                                  "ppo": {"n_steps": 16, "batch_size": 32, "n_epochs": 1}}
    raw["policies"]["A"]["total_timesteps"] = 10**6  # the batched block's budget applies, not this
    config = tmp_path / "policies.yaml"
    config.write_text(yaml.safe_dump(raw))
    run = train("A", out=tmp_path / "runs", config_file=config, backend="warp", progress=False)
    meta = (run / "meta.json").read_text()
    assert '"backend": "warp"' in meta and '"timesteps": 64' in meta
    ctrl = PPOController.from_folder(run)
    env = EndoscopeEnv("FE", force_obs=False)
    obs, _ = env.reset(seed=0)
    ctrl.reset(env.task)
    assert np.abs(ctrl.act(obs, env.task)).max() <= 0.4 + 1e-6


@pytest.mark.slow
def test_a_shipped_policy_runs_over_many_worlds():
    # The code path of the success-rate comparison (below), small enough for the CPU device: policy A in FE.
    from mjendo.batch import success_rate
    from mjendo.paths import policies_dir

    # Version 0's A reached its FE targets in 100 % of 200 CPU trials: over the worlds it must succeed too.
    r = success_rate(policies_dir() / "v0" / "A", task_config(env="FE", force_obs=False, max_steps=80, version=0),
                     2, 2, device="cpu")
    assert r["episodes"] == 2 and r["success_rate"] >= 0.5 and np.isfinite(r["mean_final_mm"])


@pytest.mark.slow
def test_shipped_e_succeeds_as_often_over_many_worlds_as_in_the_cpu_env():
    # 200 episodes over 256 worlds against the CPU env's 200 trials; the two rates agree within their 95 %
    # intervals. Affordable on a GPU only (Warp's CPU device runs ~1 env step/s per world).
    import warp as wp

    from mjendo.batch import init_quietly, success_rate
    from mjendo.evaluation import run_trials, wilson
    from mjendo.paths import policies_dir

    init_quietly(wp)
    if not wp.is_cuda_available():
        pytest.skip("needs a GPU: 200 episodes on Warp's CPU device take hours")
    cfg = task_config(env="DE", force_obs=True, max_steps=80)
    gpu = success_rate(policies_dir() / "E", cfg, 256, 200, seed=11)
    trials, _ = run_trials("E", "DE", list(range(200)))
    cpu = sum(t.success for t in trials)
    lo_g, hi_g = wilson(round(gpu["success_rate"] * 200), 200)
    lo_c, hi_c = wilson(cpu, 200)
    assert lo_g <= hi_c and lo_c <= hi_g, (gpu, cpu / 200)


def _press_force(step, steps_in: int, hold: int) -> np.ndarray:
    """Insert straight at full speed for ``steps_in`` control steps, hold still; mean force of the hold's 2nd half."""
    forces = []
    for k in range(steps_in + hold):
        f = step(np.array([0, 0, 0, 0, 0.4 if k < steps_in else 0.0]))
        if k >= steps_in + hold // 2:
            forces.append(f)
    return np.mean(forces, axis=0)


# mujoco_warp 3.17.0 (and its main branch, August 2026) builds the Jacobian of a contact with an
# interpolated (trilinear) flex from each body's *own* dofs only: right for the flex's node bodies, wrong for
# the scope's link, which moves through every ancestor joint (insertion slide, all hinges up the chain).


def _normal_rows(m, d) -> dict:
    """First constraint row (normal + friction edge) of each active scope-stomach contact, keyed by geom and element."""
    J = np.zeros((d.nefc, m.nv))
    if mujoco.mj_isSparse(m):
        mujoco.mju_sparse2dense(J, d.efc_J, d.efc_J_rownnz, d.efc_J_rowadr, d.efc_J_colind)
    else:
        J[:] = d.efc_J.reshape(d.nefc, m.nv)
    return {(int(c.geom[0]), int(c.elem[1])): J[c.efc_address] for c in (d.contact[i] for i in range(d.ncon))
            if c.efc_address >= 0 and c.geom[0] >= 0}


@pytest.mark.parametrize("fidelity", ["fast", pytest.param("full", marks=pytest.mark.slow)])
def test_a_contact_acts_on_the_whole_scope_chain(fidelity):
    # Same state in both backends (the CPU's straight press into the far wall): each contact's constraint row
    # must reach the stomach's dofs and every scope joint that moves the contact point, as MuJoCo's does.
    batch = BatchedNavigation(1, env="SE", fidelity=fidelity, device="cpu", randomize_phase=False)
    batch.reset()
    cpu = twins(batch, "SE", fidelity)[0]
    for _ in range(35):
        cpu.step(np.array([0, 0, 0, 0, 0.4]))
    m, d = cpu.task.sim.model, cpu.task.sim.data
    load_cpu_state(batch, 0, d)
    batch._mjw.forward(batch.mw, batch.d)
    warp = mujoco.MjData(batch.mjm)  # Warp's model: the same physics, the Jacobian stored as Warp chose
    batch._mjw.get_data_into(warp, batch.mjm, batch.d)
    rows_c, rows_w = _normal_rows(m, d), _normal_rows(batch.mjm, warp)
    both = sorted(set(rows_c) & set(rows_w))
    assert both, (sorted(rows_c), sorted(rows_w))
    scope = ~np.isin(m.dof_bodyid, m.flex_nodebodyid if fidelity == "fast" else m.flex_vertbodyid)
    axes = m.jnt_axis[m.dof_jntid]  # the stomach's dofs are slides along world x, y, z
    for key in both:
        jc, jw = rows_c[key], rows_w[key]
        assert np.linalg.norm(jc[scope]) > 0.1  # the reference row moves the scope (insertion, hinges)
        np.testing.assert_allclose(jw[scope], jc[scope], atol=0.02 * np.linalg.norm(jc[scope]),
                                   err_msg=f"contact {key}: the scope's part")
        # How the push is shared among an element's vertices differs between the two pipelines (measured: up
        # to 6 % on one vertex in full, 1 % in fast); the push on the wall as a whole must agree.
        net_c, net_w = jc[~scope] @ axes[~scope], jw[~scope] @ axes[~scope]
        np.testing.assert_allclose(net_w, net_c, atol=0.02 * np.linalg.norm(net_c),
                                   err_msg=f"contact {key}: the stomach's part")


@pytest.mark.slow
@pytest.mark.parametrize("fidelity", ["fast", "full"])
def test_a_held_press_settles_to_the_same_force(fidelity):
    # End-on into the far wall of the static stomach (insertion 140 mm), held 1 s: the wall's steady push on
    # the scope is a property of the end state, not of the path there (up to friction: held states are not
    # unique). Measured in task version 0: full Warp 1.19 N, CPU 1.31 N; fast 1.68 vs 1.72 N (7.8 N before
    # mjendo.warp_patch).
    batch = BatchedNavigation(1, env="SE", fidelity=fidelity, device="cpu", randomize_phase=False)
    batch.reset()
    cpu = twins(batch, "SE", fidelity)[0]
    steps_in = round(0.140 / (0.4 * batch.core.insertion_step))  # full speed to 140 mm, whatever the version
    hold = round(1.0 / batch.core.control_dt)
    fw = _press_force(lambda a: batch.step(a[None]).info["force_N"].numpy()[0], steps_in, hold)
    fc = _press_force(lambda a: cpu.step(a)[4]["force_N"], steps_in, hold)
    assert np.linalg.norm(fc) > 0.3
    assert np.linalg.norm(fw) == pytest.approx(np.linalg.norm(fc), rel=0.15), (fw, fc)
    np.testing.assert_allclose(batch.tip_pos().numpy()[0], cpu.task.sim.tip_pos(), atol=1e-3)  # same pose (m)


@pytest.mark.slow
def test_the_wall_moves_as_far_under_the_load():
    # The fidelity figure's protocol (mjendo.fidelity.target_motion): scope withdrawn to the end of its range,
    # one load cycle from the drawn start state; peak-to-peak motion of each world's target vertex.
    batch = BatchedNavigation(2, env="DE", fidelity="fast", device="cpu", seed=5)
    batch.reset()
    envs = twins(batch, "DE")
    batch.insertion[:] = batch.ins_lo
    batch._write_controls()
    for e in envs:
        e.task.sim.set_controls(np.zeros(4), e.task.sim.insertion_range[0])
    steps = int(round(2 * batch.core.sim.half_period / batch.core.sim.model.opt.timestep))
    track_w, track_c = [], []
    for _ in range(steps):
        batch._physics_step()
        track_w.append(batch.target_pos().numpy())
        for e in envs:
            e.task.sim.step(1)
        track_c.append([e.task.target_pos() for e in envs])
    p2p_w = np.linalg.norm(np.ptp(np.array(track_w), axis=0), axis=1)
    p2p_c = np.linalg.norm(np.ptp(np.array(track_c), axis=0), axis=1)
    assert (p2p_c > 2e-3).all()  # the wall really moves (millimetres)
    np.testing.assert_allclose(p2p_w, p2p_c, rtol=0.05)


def test_bad_batch_arguments():
    from mjendo.config import ConfigError

    with pytest.raises(ConfigError, match="n_worlds must be a whole number >= 1"):
        BatchedNavigation(0, env="FE", device="cpu")
    with pytest.raises(ConfigError, match="unknown solver 'PGS'; valid: CG, Newton"):
        BatchedNavigation(1, env="FE", device="cpu", solver="PGS")
    b = BatchedNavigation(1, env="FE", device="cpu")
    b.reset()
    with pytest.raises(ValueError, match="NaN"):
        b.step(np.full((1, 5), np.nan))


@pytest.mark.slow  # 40 control steps of contact on the CPU device
def test_a_world_that_runs_out_of_contact_buffers_is_reported():
    # Too few contact slots drop contacts silently in MuJoCo Warp (64 lost the deepest ones of a hard press in
    # the fast stomach): the batch must say so, naming the fix.
    batch = BatchedNavigation(1, env="SE", device="cpu", randomize_phase=False, nconmax=2, njmax=16)
    batch.reset()
    with pytest.warns(RuntimeWarning, match="ran out of contact/constraint buffers.*nconmax"):
        for _ in range(40):
            batch.step(np.array([[0, 0, 0, 0, 0.4]]))
    assert batch.overflows > 0


@pytest.mark.slow  # 45 control steps of contact on the CPU device
def test_the_fast_stomachs_solver_converges_and_a_starved_one_is_counted():
    # The fast stomach solves with Newton: on Warp (float32) the scope driven into the far wall converges within
    # the cap on every step (measured: at most 6 iterations; CG hit its 1,000 cap on 5 % of world-steps).
    batch = BatchedNavigation(1, env="SE", device="cpu", randomize_phase=False)
    batch.reset()
    touched, most = 0, 0
    for _ in range(45):
        touched += bool(batch.step(np.array([[0, 0, 0, 0, 0.4]])).info["contact"][0])
        most = max(most, int(batch._t(batch.d.solver_niter)[0]))
    assert touched >= 5 and batch.world_steps == 45
    assert batch.solver_capped == 0 and most < 50
    cg = BatchedNavigation(1, env="SE", device="cpu", solver="CG")  # the override reaches Warp, not the CPU task
    assert int(cg.mw.opt.solver) == int(mujoco.mjtSolver.mjSOL_CG) != int(cg.core.sim.model.opt.solver)
    batch.mw.opt.iterations = 1  # starved: the solves stop unconverged, and the batch counts them
    batch.step(np.array([[0, 0, 0, 0, 0.4]]))
    assert batch.solver_capped == 1 and batch.capped_fraction == pytest.approx(1 / 46)


def test_without_mujoco_warp_the_batched_backend_says_how_to_install_it(monkeypatch):
    import mjendo.batch as batch

    monkeypatch.setitem(sys.modules, "mujoco_warp", None)
    with pytest.raises(ConfigError, match=r"the batched backend needs MuJoCo Warp: install it with `pip install "
                                          r"'mjendo\[warp\]'`"):
        batch.BatchedNavigation(1, env="FE", device="cpu")


@pytest.mark.parametrize("option", ["scope_obs", "time_obs", "phase_obs", "step_obs", "depth_obs",
                                    "normal_obs", "plan_obs", "residual", "task_space", "history_obs"])
def test_the_added_observations_are_refused_by_the_batched_backend(option):
    with pytest.raises(ConfigError, match="history_obs are not available in the batched backend.*cpu"):
        BatchedNavigation(1, env="FE", device="cpu", **{option: True})


def test_randomization_is_refused_by_the_batched_backend():
    with pytest.raises(ConfigError, match="randomization .* is not available in the batched backend.*--backend cpu"):
        BatchedNavigation(1, env="DE", device="cpu", randomization=True)
