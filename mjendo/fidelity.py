"""How close the fast stomach is to the full FEM one: the protocols behind the fidelity figures.

Three measurements, each defined once here and used by ``make bench --only
fidelity``, the calibration (``python -m mjendo.fidelity compare``) and the
tests:

* **target motion**: peak-to-peak displacement (mm) of every target vertex
  (lists A and B) over one load cycle, after one cycle of settling, with the
  scope withdrawn; what a moving target does to the task;
* **press force**: the resultant contact force (N) on the scope, averaged over
  the last 0.5 s of a 1 s hold, for fixed commanded presses in the static
  stomach: end-on into the greater curvature, and the bent tip driven into
  a side wall by insertion (``PRESSES``);
* **hold speed**: tip and wall-vertex speeds (mm/s) while a press is held:
  a damped elastic system under constant load must come to rest;
* **tip tracks**: the tip's path (mm, every control step) under the open-loop
  motions that reach list A's contact-aided targets in the static stomach
  (the reachability map's demonstrators): where the wall leaves the tube that
  lies and slides on it, which held presses do not show;
* **policy tracks**: a policy's closed-loop trials in the full stomach, its
  actions replayed in a fast one: tip, target and force apart under the
  policy's own motions (``python -m mjendo.fidelity policy-tracks``);
* **target give**: how far a target moves once a policy's scope touches the
  wall, and its gain on the scope's push nearby (``python -m mjendo.fidelity give``).
"""

from __future__ import annotations

import argparse
import itertools
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import mujoco
import numpy as np

from mjendo import anatomy, scene
from mjendo.config import (
    CURRENT_VERSION,
    FIDELITIES,
    PAPER_EVAL_STEPS,
    PAPER_SUCCESS_MM,
    VERSIONS,
    ConfigError,
    Fidelity,
    StomachShape,
    fidelity_preset,
    scene_config,
)
from mjendo.scene import SOLVERS
from mjendo.sim import Simulator
from mjendo.units import from_mm, to_mm


@dataclass(frozen=True)
class Press:
    """A commanded press: bend first (cable pull), then insert to a fixed depth, hold."""

    name: str
    insertion_mm: float  # commanded insertion after the bend
    cable: int | None = None  # which cable is pulled (None: straight scope)
    pull_mm: float = 8.0  # ~80 degrees of bend
    pre_insertion_mm: float = 0.0  # insertion while bending, before the press


# Straight insertion first touches the greater curvature at about 125 mm;
# the bent presses bend at 80 mm and then push the bent tip 40 mm further.
PRESSES = (
    Press("end-on 140 mm", 140.0),
    Press("end-on 155 mm", 155.0),
    Press("bent +x, 80->120 mm", 120.0, cable=0, pre_insertion_mm=80.0),
    Press("bent +y, 80->120 mm", 120.0, cable=2, pre_insertion_mm=80.0),
    Press("bent -y, 80->120 mm", 120.0, cable=3, pre_insertion_mm=80.0),
)
HOLD_S = 1.0


def simulator(env: str, fidelity: str | Fidelity, stomach_dir: Path | None = None) -> Simulator:
    """A Simulator on the committed scene, or on a variant (preset or stomach) built in a temporary file."""
    if isinstance(fidelity, str) and stomach_dir is None:
        return Simulator(env, fidelity)
    fid = scene_config(env, fidelity).fidelity
    directory = stomach_dir or anatomy.STOMACH_DIR
    path = Path(tempfile.mkdtemp(prefix="mjendo-")) / f"{env}_{fid.name}.xml"
    path.write_text(scene.build_spec(scene_config(env, fid), anatomy.load(directory), directory).to_xml())
    return Simulator(env, "full" if fid.dof == "full" else "fast", path=path)


def _run(sim: Simulator, seconds: float, pulls: np.ndarray, insertion: float) -> None:
    sim.set_controls(pulls, insertion)
    sim.step(int(round(seconds / sim.model.opt.timestep)))


def _ramp(sim: Simulator, seconds: float, pulls0, pulls1, ins0: float, ins1: float) -> None:
    n = int(round(seconds / sim.model.opt.timestep))
    for k in range(1, n + 1):
        f = k / n
        sim.set_controls(pulls0 + f * (pulls1 - pulls0), ins0 + f * (ins1 - ins0))
        sim.step(1)


def press(sim: Simulator, p: Press) -> None:
    """Settle 0.5 s, bend and pre-insert over 0.5 s, insert to the press depth over 0.5 s."""
    sim.reset()
    zero = np.zeros(4)
    _run(sim, 0.5, zero, 0.0)
    pulls = zero.copy()
    if p.cable is not None:
        pulls[p.cable] = from_mm(p.pull_mm)
    _ramp(sim, 0.5, zero, pulls, 0.0, from_mm(p.pre_insertion_mm))
    _ramp(sim, 0.5, pulls, pulls, from_mm(p.pre_insertion_mm), from_mm(p.insertion_mm))


def press_force(sim: Simulator, p: Press, hold_s: float = HOLD_S) -> float:
    """Mean resultant contact force (N) over the last 0.5 s of the hold."""
    press(sim, p)
    dt = sim.model.opt.timestep
    sim.step(int(round((hold_s - 0.5) / dt)))
    forces = []
    for _ in range(int(round(0.5 / dt))):
        sim.step(1)
        forces.append(float(np.linalg.norm(sim.contact().force)))
    return float(np.mean(forces))


def hold_speeds(sim: Simulator, p: Press, hold_s: float = 2.0, window_s: float = 0.5) -> tuple[float, float]:
    """Tip speed and fastest wall-vertex speed (mm/s), averaged over a window after ``hold_s`` of hold.

    Averaging displacement over a window measures drift and chatter alike,
    and not the single-step jitter of a converged solve.
    """
    press(sim, p)
    dt = sim.model.opt.timestep
    sim.step(int(round(hold_s / dt)))
    tip0, wall0 = sim.tip_pos(), sim.vertices()
    sim.step(int(round(window_s / dt)))
    tip = to_mm(np.linalg.norm(sim.tip_pos() - tip0)) / window_s
    wall = to_mm(np.linalg.norm(sim.vertices() - wall0, axis=1).max()) / window_s
    return float(tip), float(wall)


def target_motion(sim: Simulator, targets: list[int]) -> np.ndarray:
    """Peak-to-peak displacement (mm) of each target over the second load cycle, scope withdrawn."""
    sim.reset()
    sim.set_controls(np.zeros(4), sim.insertion_range[0])
    cycle = 2 * sim.half_period
    sim.step(int(round(cycle / sim.model.opt.timestep)))
    lo = hi = sim.vertices(targets)
    for _ in range(int(round(cycle / sim.model.opt.timestep))):
        sim.step(1)
        x = sim.vertices(targets)
        lo, hi = np.minimum(lo, x), np.maximum(hi, x)
    return to_mm(np.linalg.norm(hi - lo, axis=1))


def all_targets(stomach_dir: Path | None = None) -> list[int]:
    st = anatomy.load(stomach_dir or anatomy.STOMACH_DIR)
    return sorted(st.targets_a + st.targets_b)


def motion_summary(env: str, fidelity: str | Fidelity, stomach_dir: Path | None = None) -> dict:
    p2p = target_motion(simulator(env, fidelity, stomach_dir), all_targets(stomach_dir))
    return {"median_mm": float(np.median(p2p)), "max_mm": float(np.max(p2p))}


def force_summary(fidelity: str | Fidelity, stomach_dir: Path | None = None) -> dict[str, float]:
    sim = simulator("SE", fidelity, stomach_dir)
    return {p.name: press_force(sim, p) for p in PRESSES}


def compare(candidate: str | Fidelity, reference: str = "full") -> dict:
    """Ratios candidate / reference for every fidelity figure (target motion median, max; press forces)."""
    out = {}
    for env in ("DE", "UE1", "UE2"):
        a, b = motion_summary(env, candidate), motion_summary(env, reference)
        out[f"{env} motion median"] = a["median_mm"] / b["median_mm"]
        out[f"{env} motion max"] = a["max_mm"] / b["max_mm"]
    fa, fb = force_summary(candidate), force_summary(reference)
    for k in fa:
        out[f"force {k}"] = fa[k] / fb[k] if fb[k] > 0 else float("nan")
    return out


# Discretisation study of the FEM stomach itself: the model of record has one tet
# layer through the 5 mm wall and 12 vertices round each ring, rings about 20 mm apart.
REFINEMENTS = {
    "2 layers": StomachShape(wall_layers=2),
    "2 layers, half edges": StomachShape(wall_layers=2, n_around=24, ring_spacing_mm=10.0),
}


def refined_stomach(shape: StomachShape, directory: Path) -> Path:
    """Build a finer stomach and carry the model of record's vertex sets over to it by position.

    Fixed, forced and target vertices are the nearest vertices of the same kind
    (outer wall or lumen) to the committed ones, so both meshes are pinned,
    loaded and judged at the same places.
    """
    base = anatomy.load()
    fine = anatomy.build(shape)
    p, inner = fine.mesh.points, fine.mesh.inner

    def nearest(ids: list[int], lumen: bool) -> list[int]:
        pool = np.flatnonzero(inner == lumen)
        return [int(pool[np.argmin(np.linalg.norm(p[pool] - base.mesh.points[i], axis=1))]) for i in ids]

    fine.fixed, fine.forced = nearest(base.fixed, False), nearest(base.forced, False)
    fine.targets_a, fine.targets_b = nearest(base.targets_a, True), nearest(base.targets_b, True)
    anatomy.save(fine, directory)
    return directory


def sweep_controls(sim: Simulator, k: int) -> None:
    """Step k of the contact-rich sweep: insert towards the far wall while sweeping the cables."""
    t = k * sim.model.opt.timestep
    pull = 0.006 * np.array([np.sin(t), -np.sin(t), np.cos(0.7 * t), -np.cos(0.7 * t)])
    sim.set_controls(pull, min(0.12, 0.05 * t))


def sweep(sim: Simulator, seconds: float, warmup_s: float = 1.0,
          record_counts: bool = False) -> tuple[float, np.ndarray | None]:
    """Physics steps/s of the sweep after a warm-up into contact, and (if asked) each step's solver iterations
    and contact count (columns 0 and 1).

    Counting costs a few microseconds per step, a few % of the free scene's step: the speed figure skips it.
    """
    dt = sim.model.opt.timestep
    for k in range(int(round(warmup_s / dt))):
        sweep_controls(sim, k)
        sim.step(1)
    n = int(round(seconds / dt))
    counts = np.zeros((n, 2), int) if record_counts else None
    t0 = time.perf_counter()
    for k in range(n):
        sweep_controls(sim, k)
        sim.step(1)
        if counts is not None:
            counts[k] = sim.data.solver_niter[:max(1, sim.data.nisland)].sum(), sim.data.ncon
    return n / (time.perf_counter() - t0), counts


def physics_rate(sim: Simulator, seconds: float = 1.0) -> float:
    """Physics steps per second while the scope presses end-on (contact-rich)."""
    press(sim, PRESSES[1])
    n = int(round(seconds / sim.model.opt.timestep))
    t0 = time.perf_counter()
    sim.step(n)
    return n / (time.perf_counter() - t0)


def refinement_study(levels: list[str]) -> None:
    """Print target motion, press forces and speed of refined full stomachs next to today's."""
    rows: dict[str, Path | None] = {"model of record": None}
    tmp = Path(tempfile.mkdtemp(prefix="mjendo-refined-"))
    for k, name in enumerate(levels):
        rows[name] = refined_stomach(REFINEMENTS[name], tmp / str(k))
    for name, d in rows.items():
        st = anatomy.load(d or anatomy.STOMACH_DIR)
        sim = simulator("SE", "full", d)
        rate = physics_rate(sim)
        print(f"\n{name}: {len(st.mesh.points)} vertices, {len(st.mesh.tets)} tets, {sim.model.nv} dofs, "
              f"{rate:.0f} physics steps/s ({rate * sim.model.opt.timestep:.2f}x realtime)", flush=True)
        for env in ("DE", "UE1", "UE2"):
            m = motion_summary(env, "full", d)
            print(f"  {env} target motion p2p median/max {m['median_mm']:.1f}/{m['max_mm']:.1f} mm", flush=True)
        for press_name, f in force_summary("full", d).items():
            print(f"  press {press_name}: {f:.3f} N", flush=True)


def solver_study(caps: list[int], tolerances: list[float], fidelity: str = "full",
                 solvers: tuple[str, ...] = ()) -> None:
    """A stomach's solver, iteration cap and tolerance against speed, convergence and every fidelity figure.

    Both iterative solves (the discrete integrator's M + hD + h^2 K and the
    contact solve) share ``iterations`` and ``tolerance``. The speed is the
    bench's contact-rich sweep (DE), where the cap binds; MuJoCo counts the
    steps whose M + hD + h^2 K solve stopped at the cap (``mjWARN_INERTIA``).
    """
    import mujoco

    preset = fidelity_preset(fidelity)
    for solver, cap, tol in itertools.product(solvers or (preset.solver,), caps, tolerances):
        fid = replace(preset, solver=solver, iterations=cap, tolerance=tol)
        sim = simulator("DE", fid)
        rate, counts = sweep(sim, 3.0, record_counts=True)
        iters = counts[:, 0]
        flagged = sim.data.warning[mujoco.mjtWarning.mjWARN_INERTIA].number
        steps = int(round(sim.data.time / sim.model.opt.timestep))
        holds = [hold_speeds(simulator("SE", fid), p) for p in PRESSES]
        forces = force_summary(fid)
        motion = {env: motion_summary(env, fid) for env in ("DE", "UE1", "UE2")}
        print(f"\n{fidelity}, {solver}, iterations {cap}, tolerance {tol:g}: sweep {rate:.0f} physics steps/s "
              f"({rate * sim.model.opt.timestep:.2f}x realtime), solver iterations median "
              f"{np.median(iters):.0f}, {np.mean(iters >= cap):.0%} of steps at the cap; "
              f"M + hD + h^2 K solve at the cap in {flagged}/{steps} steps", flush=True)
        print("  held presses, tip/wall mm/s: " + ", ".join(f"{t:.2f}/{w:.2f}" for t, w in holds))
        print("  press forces N: " + ", ".join(f"{f:.4f}" for f in forces.values()))
        print("  target motion median/max mm: " + ", ".join(
            f"{env} {m['median_mm']:.2f}/{m['max_mm']:.2f}" for env, m in motion.items()), flush=True)


def spikes(version: int, episodes: int = 20, seed: int = 0, env: str = "DE", push: float = 0.5,
           randomization=None, fidelity: str = "fast") -> dict:
    """Contact-force spikes under bang-bang random actions in a reduced-order stomach of a task version.

    Every control step records the resultant contact force and how far the tip jumped; the share of steps
    above 1, 2, 10 and 20 N, the largest force, and the tip jump on the steps above 10 N against the rest
    tell a physical lever (large force, small jump) from a numerical event (large force with a jump).
    ``push`` is the chance that a step inserts: at 0.5 (every sign equally likely) a slow scope stays near
    the cardia, above it the scope is driven into the wall as trained policies drive it. ``randomization``:
    per-episode tissue and load (TaskConfig.randomization), to check its ranges keep the physics sound.
    """
    from mjendo.task import NavigationTask

    task = NavigationTask(env=env, fidelity=fidelity, version=version, force_obs=True, max_steps=128,
                          randomization=randomization)
    rng = np.random.default_rng(seed)
    force, jump, speed = [], [], []
    for _ in range(episodes):
        task.reset(rng)
        tip = task.sim.tip_pos()
        for _k in range(128):
            action = rng.choice([-0.4, 0.4], 5)
            action[4] = 0.4 if rng.random() < push else -0.4
            res = task.step(action)
            force.append(float(np.linalg.norm(res.info["force_N"])))
            now = task.sim.tip_pos()
            jump.append(float(np.linalg.norm(now - tip)) * 1e3)
            speed.append(float(np.linalg.norm(task.sim.tip_vel())) * 1e3)
            tip = now
            if res.terminated or res.truncated:
                break
    f, j, v = np.array(force), np.array(jump), np.array(speed)
    big, strong = f > 10.0, f > 2.0
    return {"version": version, "fidelity": fidelity, "push": push, "steps": len(f), "over_1N": float(np.mean(f > 1)),
            "over_2N": float(np.mean(strong)), "over_10N": float(np.mean(big)), "over_20N": float(np.mean(f > 20)),
            "max_N": float(f.max()), "median_jump_mm": float(np.median(j)),
            "median_jump_over_2N_mm": float(np.median(j[strong])) if strong.any() else float("nan"),
            "median_jump_over_10N_mm": float(np.median(j[big])) if big.any() else float("nan"),
            "tip_speed_p99_mm_s": float(np.percentile(v, 99)), "tip_speed_max_mm_s": float(v.max())}


def tip_tracks(fidelity: str, list_name: str = "A", solimp: tuple[float, ...] | None = None,
               demos: list[int] | None = None, version: int = CURRENT_VERSION,
               ) -> tuple[np.ndarray, dict[tuple[int, int], int | None]]:
    """Each recorded SE demonstrator of the list's contact-aided points (or ``demos``) replayed open loop in
    a stomach: the tip's path (demonstrator, step, xyz in mm) and, per (demonstrator, point), the step at
    which it comes within the success distance (None: not within the trial). ``solimp``: a candidate
    impedance of the scope-wall contact in place of the scene's. ``version``: the task version, whose map
    (its lists and recorded demonstrators) and physics step both stomachs run."""
    from mjendo import targets
    from mjendo.task import NavigationTask

    pairs = targets.static_demos(list_name, targets.targets_file(version))
    demos = sorted({d for d, _ in pairs}) if demos is None else demos
    task = NavigationTask(env="SE", target_list=list_name, max_steps=10**6, randomize_phase=False,
                          fidelity=fidelity, version=version)
    if solimp is not None:
        task.sim.set_contact_solimp(solimp)
    tips = np.zeros((len(demos), targets.TRIAL_STEPS, 3))
    arrivals: dict[tuple[int, int], int | None] = {}
    for n, d in enumerate(demos):
        task.reset(np.random.default_rng(0), None)
        mine = [(i, int(np.flatnonzero(task.targets == i)[0])) for dd, i in pairs if dd == d]
        for k in range(targets.TRIAL_STEPS):
            task.step(targets.demo_action(targets.DEMOS[d], k))
            tips[n, k] = to_mm(task.sim.tip_pos())
            for i, row in mine:
                if arrivals.get((d, i)) is None:
                    near = to_mm(np.linalg.norm(task.list_positions()[row] - task.sim.tip_pos())) < PAPER_SUCCESS_MM
                    arrivals[d, i] = k + 1 if near else None
        print(f"  {fidelity}: {n + 1}/{len(demos)} demonstrators replayed", flush=True)
    return tips, arrivals


def track_comparison(candidate: str, reference: str = "full", list_name: str = "A",
                     solimp: tuple[float, ...] | None = None, version: int = CURRENT_VERSION) -> dict:
    """How far a stomach's tip paths lie from the reference's under the same motions (mm: mean, median and
    90th percentile over every step, mean over the last half of the trial), and how many (demonstrator,
    point) pairs arrive in each and arrive in one but not the other."""
    a_tips, a = tip_tracks(candidate, list_name, solimp, version=version)
    b_tips, b = tip_tracks(reference, list_name, version=version)
    dev = np.linalg.norm(a_tips - b_tips, axis=2)
    half = dev.shape[1] // 2
    return {"pairs": len(a), "mean_mm": float(dev.mean()), "median_mm": float(np.median(dev)),
            "p90_mm": float(np.percentile(dev, 90)), "late_mean_mm": float(dev[:, half:].mean()),
            f"arrive_{candidate}": sum(s is not None for s in a.values()),
            f"arrive_{reference}": sum(s is not None for s in b.values()),
            "arrive_in_one_only": sum((a[k] is None) != (b[k] is None) for k in a)}


def policy_rollouts(controller: str, env_name: str, fidelity: str, trials: int, actions: np.ndarray | None = None,
                    solimp: tuple[float, ...] | None = None, randomization=None) -> dict[str, np.ndarray]:
    """A policy's first ``trials`` evaluation trials (the evaluation's seeds and targets) in a stomach, closed
    loop, or ``actions`` (trials, steps, 5; NaN after a trial's end) replayed there open loop: per trial and
    step the action, the tip and the target (mm) and the contact force (N); ``steps`` holds each trial's
    length. ``solimp`` and ``randomization`` (TaskConfig.randomization) alter the stomach. Replaying one
    stomach's closed-loop actions in another says where the two part under the policy's own motions, which
    the demonstrators' tracks do not cover."""
    from mjendo.envs import EndoscopeEnv
    from mjendo.evaluation import EVAL_SEED_BASE, trial_targets
    from mjendo.policies import load_controller, obs_options_of, version_of

    env = EndoscopeEnv(env_name, **obs_options_of(controller), max_steps=PAPER_EVAL_STEPS, fidelity=fidelity,
                       version=version_of(controller), randomization=randomization)
    if solimp is not None:
        env.task.sim.set_contact_solimp(solimp)
    ctrl = load_controller(controller, env.task) if actions is None else None
    n, k_max = trials, PAPER_EVAL_STEPS
    out = {"action": np.full((n, k_max, 5), np.nan), "tip": np.full((n, k_max, 3), np.nan),
           "target": np.full((n, k_max, 3), np.nan), "force": np.full((n, k_max), np.nan),
           "steps": np.zeros(n, int)}
    for i, (_, target) in enumerate(trial_targets(env, n)):
        obs, _ = env.reset(seed=EVAL_SEED_BASE + i, options={"target_index": target})
        if ctrl is not None:
            ctrl.reset(env.task)
        for k in range(k_max):
            a = ctrl.act(obs, env.task) if ctrl is not None else actions[i, k]
            if np.isnan(a).any():
                break
            r = env.task.step(a)
            obs = r.obs
            out["action"][i, k] = a
            out["tip"][i, k] = to_mm(env.task.sim.tip_pos())
            out["target"][i, k] = to_mm(env.task.target_pos())
            out["force"][i, k] = float(np.linalg.norm(r.info["force_N"]))
            out["steps"][i] = k + 1
            if ctrl is not None and (r.terminated or r.truncated):
                break
        print(f"  {fidelity}: {i + 1}/{n} trials", flush=True)
    return out


def policy_track_comparison(controller: str, env_name: str, candidate: str, reference: str = "full",
                            trials: int = 65, cache: Path | None = None,
                            solimp: tuple[float, ...] | None = None) -> dict:
    """A policy's closed-loop trials in the reference stomach, their actions replayed in the candidate: how far
    the tips (and the targets) lie apart (mm, over every step), how the contact force differs, and how many
    trials end within the success distance in each. ``cache``: an .npz holding the reference's rollouts, read
    if it exists and written if not (the full stomach's take about 12 s a trial)."""
    made_by = f"{controller} in {env_name}, {reference} stomach"
    if cache is not None and Path(cache).exists():
        ref = dict(np.load(cache))
        if str(ref.pop("made_by", "")) != made_by:
            raise ConfigError(f"{cache} does not hold the trials of {made_by}: delete it or name another --cache")
    else:
        ref = policy_rollouts(controller, env_name, reference, trials)
        if cache is not None:
            Path(cache).parent.mkdir(parents=True, exist_ok=True)
            np.savez_compressed(cache, **ref, made_by=np.array(made_by))
    n = min(trials, len(ref["steps"]))
    ref = {k: v[:n] for k, v in ref.items()}
    cand = policy_rollouts(controller, env_name, candidate, n, actions=ref["action"], solimp=solimp)
    return rollout_figures(ref, cand, reference, candidate)


def rollout_figures(ref: dict[str, np.ndarray], cand: dict[str, np.ndarray], reference: str = "full",
                    candidate: str = "candidate") -> dict:
    """Figures of one stomach's rollouts against another's under the same actions (policy_track_comparison)."""
    live = ~np.isnan(ref["force"])
    tip = np.linalg.norm(cand["tip"] - ref["tip"], axis=2)[live]
    tgt = np.linalg.norm(cand["target"] - ref["target"], axis=2)[live]
    within = {name: np.nanmin(np.linalg.norm(r["tip"] - r["target"], axis=2), axis=1) < PAPER_SUCCESS_MM
              for name, r in (("ref", ref), ("cand", cand))}
    fr, fc = ref["force"][live], cand["force"][live]
    return {"trials": len(live), "steps": int(live.sum()), "tip_mean_mm": float(tip.mean()),
            "tip_median_mm": float(np.median(tip)), "tip_p90_mm": float(np.percentile(tip, 90)),
            "target_mean_mm": float(tgt.mean()), "target_p90_mm": float(np.percentile(tgt, 90)),
            f"force_mean_n_{reference}": float(fr.mean()), f"force_mean_n_{candidate}": float(fc.mean()),
            "force_abs_diff_mean_n": float(np.abs(fc - fr).mean()),
            f"contact_share_{reference}": float((fr > 0).mean()), f"contact_share_{candidate}": float((fc > 0).mean()),
            f"arrive_{reference}": int(within["ref"].sum()), f"arrive_{candidate}": int(within["cand"].sum()),
            "arrive_in_one_only": int((within["ref"] != within["cand"]).sum())}


def target_give(controller: str, fidelity: str, targets: int = 20, timestep: float | None = None,
                sigma_mm: float = 20.0, randomization=None) -> dict:
    """How far list A's contact-aided targets move under a policy's scope in the static stomach (SE): per trial
    the policy aims at one of the first ``targets`` of them; figures over the steps from its first contact on
    (the wall stands still before), at the closest approach, and the least-squares gain (mm/N) of the target's
    displacement on the scope's push on the wall, each contact weighted by exp(-d^2 / 2 sigma^2) of its distance
    d to the target: the give a reduced-order wall lacks (Randomization.target_give_mm_per_n), which
    ``randomization`` (TaskConfig.randomization) may add to measure a candidate."""
    from mjendo.envs import EndoscopeEnv
    from mjendo.evaluation import EVAL_SEED_BASE
    from mjendo.policies import load_controller, obs_options_of, version_of

    env = EndoscopeEnv("SE", **obs_options_of(controller), max_steps=PAPER_EVAL_STEPS, fidelity=fidelity,
                       version=version_of(controller), timestep_s=timestep, randomization=randomization)
    task = env.task
    ctrl = load_controller(controller, env.task)
    aimed = [t for t, c in zip(task.targets.tolist(), task.target_classes, strict=True) if c == "contact_aided"]
    moved, closest, pushes, shifts, reached = [], [], [], [], 0
    for i, target in enumerate(aimed[:targets]):
        obs, _ = env.reset(seed=EVAL_SEED_BASE + i, options={"target_index": target})
        ctrl.reset(task)
        rest, touched, best = task.target_pos().copy(), False, (np.inf, 0.0)
        for _ in range(PAPER_EVAL_STEPS):
            r = task.step(ctrl.act(obs, task))
            obs = r.obs
            shift = to_mm(task.target_pos() - rest)
            c = task.sim.contact(details=True)
            touched = touched or c.active
            if touched:
                moved.append(float(np.linalg.norm(shift)))
                pushes.append(task.push_near_target(c, sigma_mm))
                shifts.append(shift)
            best = min(best, (r.info["distance_mm"], float(np.linalg.norm(shift))))
            if r.terminated or r.truncated:
                break
        reached += bool(r.info["is_success"])
        closest.append(best[1])
        print(f"  {fidelity}: {i + 1}/{min(targets, len(aimed))} targets", flush=True)
    x, y = np.array(pushes).reshape(-1, 3), np.array(shifts).reshape(-1, 3)
    gain = float(np.sum(x * y) / max(float(np.sum(x * x)), 1e-12))
    return {"fidelity": fidelity, "trials": len(closest), "reached": reached,
            "moved_median_mm": float(np.median(moved)) if moved else 0.0,
            "moved_p90_mm": float(np.percentile(moved, 90)) if moved else 0.0,
            "moved_at_closest_median_mm": float(np.median(closest)), "gain_mm_per_n": gain}


def realised_modulus(dof: str, young: float = 150e3, poisson: float = 0.3, size_mm: float = 50.0,
                     n: int = 5) -> tuple[float, float]:
    """Young's modulus and Poisson ratio a 3D flex of ``dof`` realises for MuJoCo's ``young`` and ``poisson``.

    A free cube of n^3 vertices is pulled by 1 N on opposite faces (tributary-area loads, no gravity) and
    run to rest; returns (E_realised / young, lateral over axial strain). What the randomization's
    modulus factor means physically rests on this (docs/physics.md "Randomized tissue").
    """
    side = from_mm(size_mm)
    h = side / (n - 1)
    xml = f"""<mujoco><option gravity="0 0 0" timestep="0.005" integrator="discrete" tolerance="1e-12"
      iterations="2000"/><worldbody><flexcomp name="cube" type="grid" count="{n} {n} {n}" spacing="{h} {h} {h}"
      dim="3" radius="0.0005" mass="0.1" dof="{dof}"><elasticity young="{young}" poisson="{poisson}"
      damping="0.02"/><contact selfcollide="none" conaffinity="0" contype="0"/></flexcomp></worldbody></mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    adr, nvert = m.flex_vertadr[0], m.flex_vertnum[0]
    mujoco.mj_forward(m, d)
    x0 = d.flexvert_xpos[adr:adr + nvert].copy()
    faces = [np.flatnonzero(np.isclose(x0[:, 0], x0[:, 0].min())), np.flatnonzero(np.isclose(x0[:, 0], x0[:, 0].max()))]
    load = np.zeros(nvert)
    for sign, ids in zip((-1.0, 1.0), faces, strict=True):
        yz = x0[ids, 1:]
        edge = np.isclose(yz, yz.min(0)) | np.isclose(yz, yz.max(0))
        w = np.prod(np.where(edge, 0.5, 1.0), axis=1)  # a face's edge vertices carry half, corners a quarter
        load[ids] = sign * w / w.sum()
    jac = scene.vertex_jacobian(m, 0, list(range(nvert)), np.arange(m.nq))  # (vertices, 3, nq): linear
    d.qfrc_applied[:] = jac[:, 0, :].T @ load
    for _ in range(3000):
        mujoco.mj_step(m, d)
    x = d.flexvert_xpos[adr:adr + nvert]
    axial = (x[faces[1], 0].mean() - x[faces[0], 0].mean() - side) / side
    lateral = (np.ptp(x[:, 1]) - side) / side
    return float((1.0 / side**2) / axial / young), float(-lateral / axial)


def list_motion(env: str, version: int | None = None) -> dict:
    """How far the env's listed targets move between the two load states (mm): where each settles in the
    second half of each half cycle (mean over the task's phase snapshots there), median and 90th percentile.
    """
    from mjendo.task import NavigationTask

    task = NavigationTask(env=env, version=CURRENT_VERSION if version is None else version)
    m, d = task.sim.model, task.sim.data
    pos = []
    for state in task.start_states:
        mujoco.mj_setState(m, d, state, mujoco.mjtState.mjSTATE_INTEGRATION)
        mujoco.mj_forward(m, d)  # the flex's vertices follow its nodes in the position stage
        pos.append(task.list_positions())
    pos, n = np.array(pos), len(task.start_states)
    shift = to_mm(np.linalg.norm(pos[n // 4:n // 2].mean(0) - pos[3 * n // 4:].mean(0), axis=1))
    return {"env": env, "list": task.target_list, "targets": len(shift), "median_mm": float(np.median(shift)),
            "p90_mm": float(np.percentile(shift, 90))}


def _line(figures: dict, digits: int = 3) -> str:
    """One printed line of named figures."""
    return ", ".join(f"{k} {x:.{digits}g}" if isinstance(x, float) else f"{k} {x}" for k, x in figures.items())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m mjendo.fidelity", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    impedance = argparse.ArgumentParser(add_help=False)  # the tracks protocols' candidate contact
    impedance.add_argument("--solimp", type=float, nargs=3, metavar=("DMIN", "DMAX", "WIDTH_M"),
                           help="a candidate impedance of the scope-wall contact in place of the scene's")
    c = sub.add_parser("compare", help="ratios of a candidate fast stomach's figures to the full one's")
    c.add_argument("--cells", type=int, nargs=3, help="trilinear cell counts of the candidate")
    c.add_argument("--young-scale", type=float, help="young's modulus factor of the candidate")
    c.add_argument("--load-gains", type=float, nargs=3, metavar=("DE", "UE1", "UE2"),
                   help="gains on the periodic load of the candidate at 1, 2 and 3 x f0")
    rf = sub.add_parser("refine", help="discretisation study: the full stomach on finer meshes")
    rf.add_argument("--levels", nargs="+", choices=list(REFINEMENTS), default=list(REFINEMENTS),
                    help="refinement levels to compare with the model of record (default: all)")
    sv = sub.add_parser("solver", help="a stomach's solver, iteration cap and tolerance: speed against every figure")
    sv.add_argument("--fidelity", choices=list(FIDELITIES), default="full")
    sv.add_argument("--solvers", nargs="+", choices=list(SOLVERS), default=[], help="default: the preset's")
    sv.add_argument("--iterations", type=int, nargs="+", default=[1000])
    sv.add_argument("--tolerances", type=float, nargs="+", default=[1e-8, 1e-7, 1e-6])
    sp = sub.add_parser("spikes", help="contact-force spikes under bang-bang random actions (DE)")
    sp.add_argument("--versions", type=int, nargs="+", default=sorted(VERSIONS))
    sp.add_argument("--fidelity", choices=[f for f in FIDELITIES if f != "full"], default="fast")
    sp.add_argument("--episodes", type=int, default=20)
    sp.add_argument("--push", type=float, default=0.5, help="chance that a step inserts (0.5: unbiased)")
    sp.add_argument("--young-scales", type=float, nargs="+",
                    help="also with the wall's modulus fixed at each of these factors (the randomization's ends)")
    sub.add_parser("modulus", help="the Young's modulus and Poisson ratio MuJoCo's 3D flexes realise (a cube)")
    tr = sub.add_parser("tracks", parents=[impedance], help="a fast stomach's tip paths against the full one's "
                        "under the same motions (about 12 min on one core, 11 of them the full stomach)")
    tr.add_argument("--fidelity", choices=[f for f in FIDELITIES if f != "full"], default="fast-compliant")
    tr.add_argument("--list", default="A", choices=("A", "B"))
    tr.add_argument("--version", type=int, default=CURRENT_VERSION, choices=sorted(VERSIONS),
                    help="the task version: its map's demonstrators and its physics step (version 2: 10 ms in both)")
    pt = sub.add_parser("policy-tracks", parents=[impedance], help="a policy's closed-loop trials in the full "
                        "stomach replayed in a fast one: tip, target and force apart under the policy's own motions")
    pt.add_argument("--policy", required=True, help="a policy spec, e.g. models/policies/variants/E-paired")
    pt.add_argument("--env", default="SE", choices=("SE", "DE", "UE1", "UE2"))
    pt.add_argument("--fidelity", choices=[f for f in FIDELITIES if f != "full"], default="fast")
    pt.add_argument("--trials", type=int, default=65)
    pt.add_argument("--cache", type=Path, help="an .npz of the full stomach's rollouts: read if present, else written")
    gv = sub.add_parser("give", help="how far contact-aided targets move under a policy's scope (SE), per stomach")
    gv.add_argument("--policy", default="E", help="a policy spec (default: the shipped E)")
    gv.add_argument("--fidelities", nargs="+", choices=list(FIDELITIES), default=["full", "fast-coarse"])
    gv.add_argument("--targets", type=int, default=20, help="list A's first N contact-aided targets, a trial each")
    gv.add_argument("--timestep", type=float, help="physics step (s) in every stomach instead of each one's own")
    lm = sub.add_parser("motion", help="how far the listed targets move between the two load states")
    lm.add_argument("--envs", nargs="+", default=["DE", "UE1", "UE2"])
    args = ap.parse_args(argv)
    solimp = tuple(args.solimp) if getattr(args, "solimp", None) else None
    if args.cmd == "tracks":
        print(_line(track_comparison(args.fidelity, "full", args.list, solimp, args.version)))
        return 0
    if args.cmd == "policy-tracks":
        from mjendo import cli
        from mjendo.policies import PolicyError

        if args.trials < 1:
            ap.error(f"--trials must be >= 1, not {args.trials}")
        return cli.run(lambda: print(_line(policy_track_comparison(
            args.policy, args.env, args.fidelity, "full", args.trials, args.cache, solimp))), ConfigError, PolicyError)
    if args.cmd == "give":
        from mjendo import cli
        from mjendo.policies import PolicyError

        if args.targets < 1:
            ap.error(f"--targets must be >= 1, not {args.targets}")
        return cli.run(lambda: [print(_line(target_give(args.policy, f, args.targets, args.timestep)), flush=True)
                                for f in args.fidelities], ConfigError, PolicyError)
    if args.cmd == "motion":
        for env in args.envs:
            print(_line(list_motion(env)), flush=True)
        return 0
    if args.cmd == "modulus":
        for poisson in (0.0, 0.3, 0.45):
            for dof in ("full", "trilinear"):
                e, nu = realised_modulus(dof, poisson=poisson)
                print(f"poisson {poisson}: {dof:<9} realised E / young {e:.3f}, lateral / axial strain {nu:.3f}")
        return 0
    if args.cmd == "spikes":
        from mjendo import cli

        def report() -> None:
            for v in args.versions:
                rows = [spikes(v, args.episodes, push=args.push, fidelity=args.fidelity)]
                rows += [{"young_scale": k, **spikes(v, args.episodes, push=args.push, fidelity=args.fidelity,
                                                     randomization={"young_scale": (k, k)})}
                         for k in args.young_scales or []]
                for row in rows:
                    print(_line(row, digits=4), flush=True)

        return cli.run(report, ConfigError)
    if args.cmd == "refine":
        refinement_study(args.levels)
        return 0
    if args.cmd == "solver":
        solver_study(args.iterations, args.tolerances, args.fidelity, tuple(args.solvers))
        return 0
    given = {"cellcount": args.cells, "young_scale": args.young_scale, "load_gains": args.load_gains}
    changes = {k: tuple(v) if isinstance(v, list) else v for k, v in given.items() if v}
    for k, v in compare(replace(fidelity_preset("fast"), name="candidate", **changes)).items():
        print(f"{k:<40}{v:8.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
