"""``make bench``: physics and environment speed, one process per figure, medians of repeats.

Each figure runs in a fresh single-threaded process so figures do not share
caches or compete for a core; repeats are timed back to back and the median
is reported. ``--only fidelity`` prints the fast stomach next to the full
FEM one (target motion, press forces, held-press speeds; the calibration
figures of docs/physics.md, protocols in :mod:`mjendo.fidelity`).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import statistics
import subprocess
import sys
import time

import numpy as np

from mjendo.config import CONDITIONS, CURRENT_VERSION, FIDELITIES, VERSIONS

SCENES = [("FE", "fast")] + [(e, f) for f in FIDELITIES for e in CONDITIONS if CONDITIONS[e].has_stomach]


def physics_figure(env: str, fidelity: str, repeats: int, seconds: float) -> dict:
    from mjendo.fidelity import sweep
    from mjendo.sim import Simulator

    sim = Simulator(env, fidelity)
    dt = sim.model.opt.timestep
    seconds = max(seconds, 50 * dt)
    rates, contacts = [], []
    for r in range(repeats):
        rates.append(sweep(sim, seconds, warmup_s=1.0 if r == 0 else 0.0)[0])
        contacts.append(sim.data.ncon)
    med = statistics.median(rates)
    return {"figure": "physics", "env": env, "fidelity": fidelity, "nv": int(sim.model.nv),
            "steps_per_s": med, "realtime_factor": med * dt, "contacts": int(np.median(contacts))}


def env_figure(env: str, fidelity: str, repeats: int, steps: int, version: int = CURRENT_VERSION) -> dict:
    """env.step rate, and its cost over the bare physics it runs.

    The bare run replays the same controls from the same start state with
    ``mj_step`` only, so both time exactly the same physics.
    """
    import mujoco

    from mjendo.envs import EndoscopeEnv

    e = EndoscopeEnv(env, fidelity=fidelity, force_obs=True, version=version)
    rng = np.random.default_rng(0)
    m, d, sub = e.task.sim.model, e.task.sim.data, e.task.substeps
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state = np.empty(mujoco.mj_stateSize(m, spec))
    env_rates, ratio = [], []
    for rep in range(repeats):
        e.reset(seed=rep)
        mujoco.mj_getState(m, d, state, spec)
        actions = rng.uniform(-0.4, 0.4, (steps, 5))
        actions[:, 4] = np.abs(actions[:, 4])  # keep inserting: contacts happen
        ctrls = np.empty((steps, m.nu))
        t0 = time.perf_counter()
        for k, a in enumerate(actions):
            _, _, term, trunc, _ = e.step(a)
            ctrls[k] = d.ctrl
            if term or trunc:
                steps = k + 1
                break
        t_env = time.perf_counter() - t0
        mujoco.mj_setState(m, d, state, spec)
        t0 = time.perf_counter()
        for k in range(steps):
            d.ctrl[:] = ctrls[k]
            for _ in range(sub):
                mujoco.mj_step(m, d)
        t_phys = time.perf_counter() - t0
        env_rates.append(steps / t_env)
        ratio.append(t_env / t_phys)
    return {"figure": "env", "env": env, "fidelity": fidelity, "env_steps_per_s": statistics.median(env_rates),
            "step_cost_over_physics": statistics.median(ratio), "substeps": sub,
            "control_period_s": e.task.control_dt, "version": version}


def episodes_figure(env: str, fidelity: str, steps: int, randomized: str, seed: int) -> dict:
    """env steps/s over whole training episodes (128 steps), resets included: the built-in stomach, randomized
    tissue and load ('tissue'), or those drawn in one of the training anatomies per episode ('anatomy')."""
    from mjendo.envs import EndoscopeEnv

    e = EndoscopeEnv(env, fidelity=fidelity, randomization=True if randomized != "none" else None,
                     anatomy="train" if randomized == "anatomy" else None)
    for k in range(len(e.anatomies)):  # built once per stomach in a run (about 0.5 s each), not per episode
        e.anatomy_task(k)
    rng = np.random.default_rng(seed)
    done, episode = 0, 0
    t0 = time.perf_counter()
    while done < steps:
        e.reset(seed=seed * 1000 + episode)
        episode += 1
        for _ in range(e.task.cfg.max_steps):
            a = rng.uniform(-0.4, 0.4, 5)
            a[4] = abs(a[4])  # keep inserting: contacts happen
            done += 1
            _, _, term, trunc, _ = e.step(a)
            if term or trunc:
                break
    return {"figure": "episodes", "env_steps_per_s": done / (time.perf_counter() - t0), "episodes": episode}


def training_figure(vec_env: str, steps: int, n_envs: int | None = None) -> dict:
    """PPO throughput for policy E's config, updates included, with a Dummy or Subproc VecEnv."""
    import torch
    from stable_baselines3.common.logger import Logger
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecNormalize

    from mjendo.paths import TRAINING_CONFIG
    from mjendo.train import build_ppo, load_config, make_env

    torch.set_num_threads(1)
    cfg = load_config("E", TRAINING_CONFIG, n_envs=n_envs)
    # Every variant collects the config's samples per update, however many envs share them.
    rollout = load_config("E", TRAINING_CONFIG).rollout_size
    cfg.ppo.n_steps = max(1, rollout // cfg.n_envs)
    vec = SubprocVecEnv if vec_env == "subproc" else DummyVecEnv
    venv = VecNormalize(vec([make_env(cfg, i) for i in range(cfg.n_envs)]), gamma=cfg.ppo.gamma)
    model = build_ppo(cfg, venv)
    model.set_logger(Logger(None, []))  # no output: SB3's default logger leaves an empty /tmp/SB3-* folder per call
    model.learn(2048)  # warm-up: process start, first rollout
    t0 = time.perf_counter()
    model.learn(steps, reset_num_timesteps=False)
    rate = steps / (time.perf_counter() - t0)
    venv.close()
    return {"figure": "training", "vec_env": vec_env, "steps_per_s": rate, "n_envs": cfg.n_envs}


def video_figure(steps: int) -> dict:
    """Headless 640x480 recording rate, simulation included (random policy in DE)."""
    import tempfile
    from pathlib import Path

    from mjendo.viewer import record

    with tempfile.TemporaryDirectory() as d:
        record(Path(d) / "warm.mp4", policy="random", env_name="DE", episodes=1, max_steps=5)
        t0 = time.perf_counter()
        r = record(Path(d) / "bench.mp4", policy="random", env_name="DE", episodes=1, max_steps=steps,
                   width=640, height=480)
        dt = time.perf_counter() - t0
    return {"figure": "video", "frames_per_s": r["frames"] / dt, "frames": r["frames"]}


def fidelity_figure(env: str, fidelity: str) -> dict:
    """Target motion (DE/UE1/UE2), or press forces and held-press speeds (SE): mjendo.fidelity's protocols."""
    from mjendo import fidelity as fid_protocols

    if env == "SE":
        sim = fid_protocols.simulator("SE", fidelity)
        forces = {p.name: fid_protocols.press_force(sim, p) for p in fid_protocols.PRESSES}
        speeds = {p.name: fid_protocols.hold_speeds(sim, p) for p in fid_protocols.PRESSES}
        return {"figure": "fidelity", "env": env, "fidelity": fidelity, "forces": forces, "speeds": speeds}
    return {"figure": "fidelity", "env": env, "fidelity": fidelity, **fid_protocols.motion_summary(env, fidelity)}


def batched_figure(env: str, fidelity: str, worlds: int, steps: int, solver: str | None = None) -> dict:
    """Env steps/s of the batched backend (task logic included) at one world count, on the device it finds."""
    from mjendo.batch import BatchedNavigation
    from mjendo.scene import SOLVERS

    b = BatchedNavigation(worlds, env=env, fidelity=fidelity, solver=solver)
    b.reset()
    rng = np.random.default_rng(0)
    actions = rng.uniform(-0.4, 0.4, (steps + 2, worlds, 5))
    actions[..., 4] = np.abs(actions[..., 4])  # keep inserting: contacts happen
    for a in actions[:2]:  # compile and warm up
        b.step(a)
    b._wp.synchronize()
    t0 = time.perf_counter()
    for a in actions[2:]:
        b.step(a)
    b._wp.synchronize()
    rate = steps * worlds / (time.perf_counter() - t0)
    return {"figure": "batched", "env": env, "fidelity": fidelity, "worlds": worlds, "device": b.wp_device,
            "env_steps_per_s": rate, "physics_steps_per_s": rate * b.core.substeps,
            "solver_capped": b.capped_fraction,
            "solver": next(k for k, v in SOLVERS.items() if int(v) == int(b.mw.opt.solver))}


def _child(args) -> None:
    if args.figure == "physics":
        out = physics_figure(args.env, args.fidelity, args.repeats, args.seconds)
    elif args.figure == "video":
        out = video_figure(args.steps)
    elif args.figure == "training":
        out = training_figure(args.vec_env, args.steps, args.n_envs)
    elif args.figure == "env":
        out = env_figure(args.env, args.fidelity, args.repeats, args.steps, args.version)
    elif args.figure == "episodes":
        out = episodes_figure(args.env, args.fidelity, args.steps, args.randomized, args.seed)
    elif args.figure == "batched":
        out = batched_figure(args.env, args.fidelity, args.worlds, args.steps, args.solver)
    else:
        out = fidelity_figure(args.env, args.fidelity)
    print(json.dumps(out))


def _run(argv: list[str]) -> dict:
    env = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", PYTHONWARNINGS="ignore")
    res = subprocess.run([sys.executable, "-m", "mjendo.bench", "--child", *argv], capture_output=True,
                         text=True, env=env, check=False)
    if res.returncode:
        raise RuntimeError(f"bench figure {argv} failed:\n{res.stderr[-2000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def _has_warp() -> bool:
    import importlib.util

    return importlib.util.find_spec("mujoco_warp") is not None


def _batched_table(max_worlds: int | None, min_worlds: int, fidelities: list[str], solvers: list[str]) -> None:
    """MuJoCo Warp: env steps/s (task logic included) against the number of worlds, DE fast and full."""
    import warp as wp

    from mjendo.batch import init_quietly

    init_quietly(wp)
    gpu = wp.is_cuda_available()
    top = max_worlds or (8192 if gpu else 8)
    counts = [n for n in (1, 2, 8, 64, 256, 1024, 2048, 4096, 8192) if min_worlds <= n <= top]
    print(f"\n{'batched (MuJoCo Warp)':<24}{'worlds':>8}{'env steps/s':>14}{'physics steps/s':>18}"
          f"{'solves at cap':>15}   device")
    for fid, solver, n in itertools.product(fidelities, solvers or [None], counts):
        r = _run(["--figure", "batched", "--env", "DE", "--fidelity", fid, "--worlds", str(n), "--steps",
                  "20" if gpu else "3"] + (["--solver", solver] if solver else []))
        print(f"{'DE ' + fid + ' (' + r['solver'] + ')':<24}{n:>8}{r['env_steps_per_s']:>14.0f}"
              f"{r['physics_steps_per_s']:>18.0f}{r['solver_capped']:>14.1%}   {r['device']}", flush=True)


def _fidelity_table() -> None:
    """Fast next to full: target motion under the load, press forces, speeds while a press is held."""
    print(f"\n{'target motion p2p (mm)':<24}{'fast median/max':>18}{'full median/max':>18}{'fast/full':>14}")
    for env in ("DE", "UE1", "UE2"):
        a, b = (_run(["--figure", "fidelity", "--env", env, "--fidelity", f]) for f in ("fast", "full"))
        print(f"{env:<24}{a['median_mm']:>9.1f}/{a['max_mm']:<8.1f}{b['median_mm']:>9.1f}/{b['max_mm']:<8.1f}"
              f"{a['median_mm'] / b['median_mm']:>7.2f}/{a['max_mm'] / b['max_mm']:<6.2f}", flush=True)
    a, b = (_run(["--figure", "fidelity", "--env", "SE", "--fidelity", f]) for f in ("fast", "full"))
    print(f"\n{'press (SE), held 1 s':<24}{'fast N':>10}{'full N':>10}{'fast/full':>11}"
          f"{'fast tip/wall mm/s':>22}{'full tip/wall mm/s':>22}")
    for name, fa in a["forces"].items():
        fb = b["forces"][name]
        (ta, wa), (tb, wb) = a["speeds"][name], b["speeds"][name]
        print(f"{name:<24}{fa:>10.3f}{fb:>10.3f}{fa / fb:>11.2f}{ta:>12.2f}/{wa:<9.2f}{tb:>12.2f}/{wb:<9.2f}")
    print("speeds: mean over 0.5 s after 2 s of hold (mjendo.fidelity.hold_speeds)", flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m mjendo.bench", description=__doc__)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--figure", default="physics",
                    choices=["physics", "env", "episodes", "fidelity", "training", "video", "batched"])
    ap.add_argument("--worlds", type=int, default=1, help="batched figure: worlds")
    ap.add_argument("--max-worlds", type=int, help="batched figures: largest world count (default: 8 on a CPU, "
                    "8192 on a GPU)")
    ap.add_argument("--min-worlds", type=int, default=1, help="batched figures: smallest world count")
    ap.add_argument("--batched-fidelities", default="fast,full", help="batched figures: stomachs, comma-separated")
    ap.add_argument("--batched-solvers", default="", help="batched figures: constraint solvers to compare, "
                    "comma-separated (CG, Newton; default: each scene's own)")
    ap.add_argument("--solver", help=argparse.SUPPRESS)
    ap.add_argument("--seed", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--randomized", default="none", choices=["none", "tissue", "anatomy"], help=argparse.SUPPRESS)
    ap.add_argument("--vec-env", default="subproc", choices=["subproc", "dummy"])
    ap.add_argument("--n-envs", type=int, help="training figure: environments (default: policy E's config)")
    ap.add_argument("--env", default="DE")
    ap.add_argument("--fidelity", default="fast")
    ap.add_argument("--version", type=int, default=CURRENT_VERSION, help=argparse.SUPPRESS)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--seconds", type=float, default=1.0, help="simulated seconds per physics repeat")
    ap.add_argument("--steps", type=int, default=200, help="env steps per env repeat")
    ap.add_argument("--only", choices=["physics", "env", "randomization", "fidelity", "training", "video",
                                       "batched"],
                    help="run one group of figures")
    args = ap.parse_args(argv)
    if args.child:
        _child(args)
        return 0
    common = ["--repeats", str(args.repeats), "--seconds", str(args.seconds), "--steps", str(args.steps)]
    print(f"mjendo bench: medians of {args.repeats} repeats, one process per figure, 1 thread")
    if args.only in (None, "physics"):
        print(f"\n{'scene':<6}{'fidelity':<9}{'dofs':>6}{'steps/s':>10}{'x realtime':>12}{'contacts':>10}")
        for env, fid in SCENES:
            r = _run(["--figure", "physics", "--env", env, "--fidelity", fid, *common])
            print(f"{env:<6}{fid:<9}{r['nv']:>6}{r['steps_per_s']:>10.0f}{r['realtime_factor']:>12.2f}"
                  f"{r['contacts']:>10}", flush=True)
    if args.only in (None, "env"):
        # Every task version and its stomachs in one run: a control step of version 1 simulates 100 ms, of
        # version 0 30 ms.
        print(f"\n{'env (force-aware)':<22}{'env steps/s':>12}{'step / bare physics':>22}{'sim s / wall s':>16}")
        for version, env, fid in [(v, "DE", f) for v in sorted(VERSIONS, reverse=True) for f in FIDELITIES
                                  if FIDELITIES[f].first_version <= v]:
            r = _run(["--figure", "env", "--env", env, "--fidelity", fid, "--version", str(version), *common])
            print(f"{env + ' ' + fid + ' v' + str(version):<22}{r['env_steps_per_s']:>12.0f}"
                  f"{r['step_cost_over_physics']:>22.3f}{r['env_steps_per_s'] * r['control_period_s']:>16.1f}",
                  flush=True)
    if args.only in (None, "randomization"):
        # Alternating repeats, each in a fresh process: a noisy spell on the machine hits both alike.
        labels = {"none": "built-in stomach", "tissue": "randomized tissue and load",
                  "anatomy": "+ training anatomies"}
        from mjendo import anatomy, targets

        missing = [m for m in anatomy.members("train") if not targets.map_path(anatomy.stomach_dir(m)).exists()]
        if missing:  # the anatomy row needs every training stomach's map
            labels.pop("anatomy")
            print(f"\n(no anatomy row: {len(missing)} training stomachs have no map yet; "
                  "`python -m mjendo.targets map --anatomy train`)")
        rates: dict[str, list[float]] = {k: [] for k in labels}
        for rep in range(args.repeats):
            for randomized in rates:
                r = _run(["--figure", "episodes", "--env", args.env, "--fidelity", args.fidelity, "--steps",
                          str(max(args.steps, 512)), "--seed", str(rep), "--randomized", randomized])
                rates[randomized].append(r["env_steps_per_s"])
        print(f"\n{'whole episodes, ' + args.env + ' ' + args.fidelity:<30}{'env steps/s':>12}   repeats")
        for randomized, rs in rates.items():
            print(f"{labels[randomized]:<30}{statistics.median(rs):>12.0f}   " + " ".join(f"{x:.0f}" for x in rs))
        for randomized in list(rates)[1:]:
            ratio = statistics.median(b / a for a, b in zip(rates["none"], rates[randomized], strict=True))
            print(f"{labels[randomized]} / built-in (median of paired ratios): {ratio:.2f}", flush=True)
    if args.only in (None, "training"):
        # The variants alternate, so a noisy spell on the machine hits all of them alike; each collects
        # E's 2048 samples per update. E's config has 8 envs in one process (dummy x8).
        rates: dict[tuple[str, int], list[float]] = {("dummy", 8): [], ("dummy", 2): [], ("subproc", 2): []}
        for _ in range(args.repeats):
            for vec, n in rates:
                r = _run(["--figure", "training", "--vec-env", vec, "--n-envs", str(n), "--steps", "8192"])
                rates[vec, n].append(r["steps_per_s"])
        print(f"\n{'PPO training, policy E':<24}{'steps/s (updates incl.)':>26}   repeats")
        for (vec, n), rs in rates.items():
            print(f"{vec + ' x' + str(n):<24}{statistics.median(rs):>26.0f}   " + " ".join(f"{x:.0f}" for x in rs))
        for vec, n in [("dummy", 2), ("subproc", 2)]:
            ratio = statistics.median(s / d for s, d in zip(rates[vec, n], rates["dummy", 8], strict=True))
            print(f"{vec} x{n} / dummy x8 (median of paired ratios): {ratio:.2f}", flush=True)
    if args.only in (None, "video"):
        r = _run(["--figure", "video", "--steps", "120"])
        print(f"\nheadless recording 640x480, DE, simulation included: {r['frames_per_s']:.1f} frames/s "
              f"({r['frames']} frames)", flush=True)
    if args.only in (None, "fidelity"):
        _fidelity_table()
    if args.only == "batched" or (args.only is None and _has_warp()):
        _batched_table(args.max_worlds, args.min_worlds, args.batched_fidelities.split(","),
                       [x for x in args.batched_solvers.split(",") if x])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
