"""``make eval``: the paper's study measured by mjendo, next to the paper's tables.

Every shipped policy (A-E) and the DLS baseline run N seeded 80-step trials in
SE and DE (target list A) and UE1, UE2 (list B); policy A also in FE (list F).
Trial i aims at target i mod the list's length, at the load phase its seed
draws. Trials are spread over worker processes. Writes to ``--out`` (default
``runs/eval/<fidelity>/``, untracked): trials.csv.gz (one row per trial, with the
safety and target-motion measures), summary.csv, report.md (ours next to the
paper's, with the command, commit and wall time) and the figures.
"""

from __future__ import annotations

import argparse
import csv
import gzip
import io
import json
import math
import os
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from multiprocessing import get_context
from pathlib import Path
from typing import IO

import numpy as np

from mjendo import cli, paths, rollout, targets
from mjendo.artifacts import PolicyError
from mjendo.config import (
    CONDITIONS,
    CURRENT_VERSION,
    FIDELITIES,
    PAPER_EVAL_STEPS,
    PAPER_RESULTS,
    PAPER_SUCCESS_MM,
    POLICY_NAMES,
    VERSIONS,
    ConfigError,
    fidelity_preset,
    task_config,
)
from mjendo.units import to_mm

CONTROLLERS = (*POLICY_NAMES, "baseline")
# Trial seeds start here, disjoint from every other seed range: training environments seed * 1000 + rank
# (train.make_env), training's periodic evaluations 10,000,000 + (train.TRAINING_EVAL_SEED), the study's
# validation 20,000,000 + (study.VALIDATION_SEED). No training episode replays an evaluation trial.
EVAL_SEED_BASE = 30_000_000


@dataclass(frozen=True)
class Conditions:
    """What a cell's trials run in besides the policy and the environment, in one place: TaskConfig fields,
    checked once before any trial, passed whole to the workers and described whole in the report."""

    fidelity: str = "fast"
    version: int = CURRENT_VERSION  # the baseline's task version; a policy acts in the one it trained in
    anatomy: int | str | None = None  # another stomach or a set (TaskConfig.anatomy): trials spread over a set
    steps: int = PAPER_EVAL_STEPS  # the trial's length (the paper's 80)
    randomization: bool | dict | None = None  # tissue, load, friction and noise drawn per trial from its seed
    timestep: float | None = None  # physics step instead of the stomach's own (TaskConfig.timestep_s)
    contact_time_constant: float | None = None  # TaskConfig.contact_time_constant_s
    force_off: bool = False  # force-aware policies read no contact and no force (TaskConfig.force_off)

    def task(self, controller: str) -> dict:
        """The TaskConfig fields of a controller's trials."""
        from mjendo.policies import version_of

        return {"max_steps": self.steps, "fidelity": self.fidelity, "version": version_of(controller, self.version),
                "anatomy": self.anatomy, "randomization": self.randomization, "timestep_s": self.timestep,
                "contact_time_constant_s": self.contact_time_constant, "force_off": self.force_off}

    def check(self, controllers) -> None:
        """A bad value, or a stomach without a map, stops here, not as the same error in every trial."""
        from mjendo.policies import version_of

        if self.steps < 1:
            raise ConfigError(f"--trial-steps must be >= 1, not {self.steps}")
        task_config(**{k: v for k, v in self.task("baseline").items() if k != "max_steps"})
        for v in {version_of(c, self.version) for c in controllers}:
            targets.require_maps(self.anatomy, v)

    def describe(self, versions: tuple[int, ...]) -> str:
        """The report's line on the stomach and the physics; ``versions``: the task versions acted in."""
        step = ", ".join(f"{1000 * (self.timestep or fidelity_preset(self.fidelity, v).timestep_s):g} ms"
                         + (f" (task version {v})" if len(versions) > 1 or v != CURRENT_VERSION else "")
                         for v in versions)
        return (f"Stomach: {FIDELITIES[self.fidelity].description} (`fidelity={self.fidelity}`)"
                + ("" if self.anatomy is None else f", anatomy `{self.anatomy}` (trials spread evenly over its "
                   "stomachs)")
                + ("" if self.randomization is None else
                   f", randomized per trial (`{json.dumps(self.randomization)}`)")
                + f", physics step {step}"
                + ("" if self.timestep is None else " (not the stomach's own)")
                + ("" if self.contact_time_constant is None
                   else f", contact and anchor time constant {1000 * self.contact_time_constant:g} ms (not the "
                   "scene's)")
                + (", **force sensor off**: force-aware policies read contact 0 and force 0 (`--force-off`)"
                   if self.force_off else "") + ".  ")


def default_out(fidelity: str) -> Path:
    """Untracked by default (runs/ is ignored): a quick `make eval TRIALS=10` never touches the committed study."""
    return paths.RUNS / "eval" / fidelity


def _trained_in_fe(controller: str) -> bool:
    if controller == "A":
        return True
    if controller in CONTROLLERS:
        return False
    from mjendo import artifacts

    return artifacts.read_meta(artifacts.resolve(controller)).get("task", {}).get("env") == "FE"


def cells(controllers=CONTROLLERS) -> list[tuple[str, str]]:
    """(controller, environment) pairs of the study: SE, DE, UE1, UE2, and FE for policies trained there."""
    out = []
    for c in controllers:
        out += [(c, "FE")] if _trained_in_fe(c) else []
        out += [(c, e) for e in CONDITIONS if CONDITIONS[e].has_stomach]
    return out


def check_controllers(controllers) -> None:
    """Letters, baseline, published variants or policy folders; anything else is refused before any work starts."""
    from mjendo import artifacts

    for c in controllers:
        if c in CONTROLLERS:
            continue
        folder = artifacts.resolve(c, others=tuple(x for x in CONTROLLERS if x not in POLICY_NAMES))
        if not (artifacts.model_home(folder) / artifacts.MODEL_FILE).exists():
            raise ConfigError(f"{c} holds no {artifacts.MODEL_FILE}: pass a finished run or policy folder")


def guard_overwrite(out: Path, trials: int, overwrite: bool) -> None:
    """Refuse to replace a report made with more trials per cell (e.g. the committed 200-trial study)."""
    summary = out / "summary.csv"
    if overwrite or not summary.exists():
        return
    with open(summary) as f:
        before = max((int(r["trials"]) for r in csv.DictReader(f) if r.get("trials", "").isdigit()), default=0)
    if before > trials:
        raise ConfigError(f"{out} holds a report made with {before} trials per cell; this run has {trials}. "
                          "Write elsewhere with --out, or pass --overwrite to replace it")


@dataclass
class Trial:
    controller: str
    env: str
    trial: int
    seed: int
    target: int
    success: bool
    final_mm: float
    steps: int
    steps_to_success: float
    exited: bool
    mean_force_n: float
    peak_force_n: float
    first_contact_step: float
    contact_share: float = math.nan  # share of steps in contact with the wall
    force_at_end_n: float = math.nan  # contact force at the last step (at success, for successful trials)
    over_1n_share: float = math.nan  # share of steps with a contact force above 1 N (CathSim's safety measure)
    over_2n_share: float = math.nan  # ... above 2 N
    target_motion_mm: float = math.nan  # farthest the target moved from where it was at the trial's start
    duration_s: float = math.nan  # simulated time of the trial
    error: str = ""
    anatomy: str = ""  # the stomach (a generated one's seed, a folder; "" the built-in one)
    target_class: str = ""  # the target's class in its stomach's map (free, contact_aided)


def trial_targets(env, n: int, first: int = 0) -> list[tuple[int | None, int]]:
    """Trials by design: (stomach index, target) of trials first .. first + n - 1.

    In one stomach trial i aims at target i mod len(list); over a set of m stomachs trial i runs in stomach
    i mod m and aims at the ((i // m) mod len)-th target of its list in spread_order: every stomach as often,
    and a stomach tried fewer times than its list is long still gets targets from the whole list (a list
    holds its free targets first). The load phase is drawn by the trial's seed.
    """
    m = len(env.anatomies)
    if m == 1:
        listed = env.task.targets.tolist()
        return [(None, listed[i % len(listed)]) for i in range(first, first + n)]
    lists = [env.anatomy_task(k).targets.tolist() for k in range(m)]
    orders = [spread_order(len(t)) for t in lists]
    return [(i % m, lists[i % m][orders[i % m][(i // m) % len(lists[i % m])]]) for i in range(first, first + n)]


def spread_order(n: int) -> list[int]:
    """0 .. n-1 in the van der Corput order: every prefix spreads evenly over the range."""
    out, seen, j = [], set(), 0
    while len(out) < n:  # ends by j = 2n: the dyadic points then fall in every 1/n-wide bin
        x, f, k = 0.0, 0.5, j
        while k:
            x, f, k = x + f * (k & 1), f / 2, k >> 1
        if int(x * n) not in seen:
            seen.add(int(x * n))
            out.append(int(x * n))
        j += 1
    return out


def trial_records(env, ctrl, name: str, seeds: list[int], keep_paths: bool = False,
                  first: int = 0) -> tuple[list, list]:
    """Seeded trials of a controller in an env (its max_steps is the trial length); per-trial records and paths.

    ``seeds`` are the seeds of trials ``first``, ``first`` + 1, ...: trial i aims at target i mod len(list)
    and starts at the load phase its seed draws.
    """
    trials, paths = [], []
    for i, (seed, (where, target)) in enumerate(zip(seeds, trial_targets(env, len(seeds), first), strict=True),
                                                start=first):
        forces, tips, dists, contact_step, contact_pos = [], [], [], math.nan, None
        start, motion = None, 0.0
        for s in rollout.episode(env, ctrl, seed=seed, target=target, anatomy_index=where):
            here = env.task.target_pos()
            start = here if start is None else start
            motion = max(motion, float(np.linalg.norm(here - start)))
            if s.index == 0:
                continue
            info = s.info
            forces.append(float(np.linalg.norm(info["force_N"])))
            dists.append(info["distance_mm"])
            tip = to_mm(env.task.sim.tip_pos())
            if keep_paths:
                tips.append(tip)
            if info["contact"] and math.isnan(contact_step):
                contact_step, contact_pos = s.index, tip
        ok, k = bool(info["is_success"]), s.index
        f = np.array(forces)
        trials.append(Trial(name, env.task.cfg.env, i, seed, info["target_index"], ok, info["distance_mm"], k,
                            float(k) if ok else math.nan, bool(info["exited"]), float(np.mean(f)),
                            float(np.max(f)), contact_step, float(np.mean(f > 0)), float(f[-1]),
                            float(np.mean(f > 1.0)), float(np.mean(f > 2.0)), float(to_mm(motion)),
                            k * env.task.control_dt, "", anatomy_name(env.task.cfg.anatomy),
                            str(env.task.target_classes[env.task._row])))
        if keep_paths:
            paths.append({"target": info["target_index"], "target_mm": to_mm(start), "tip_mm": np.array(tips),
                          "force_n": np.array(forces),
                          "distance_mm": np.array(dists), "contact_mm": contact_pos, "success": ok})
    return trials, paths


def anatomy_name(anatomy) -> str:
    return "" if anatomy is None else str(anatomy)


def run_trials(controller: str, env_name: str, seeds: list[int], keep_paths: bool = False, first: int = 0,
               conditions: Conditions = Conditions()) -> tuple[list, list]:
    """Run trials of one cell; a broken policy marks every trial with its error instead of raising."""
    from mjendo.envs import EndoscopeEnv
    from mjendo.policies import load_controller, obs_options_of

    try:
        env = EndoscopeEnv(env_name, **obs_options_of(controller), **conditions.task(controller))
        ctrl = load_controller(controller, env.task)
    except Exception as exc:  # reported per cell, the other cells still run
        msg = f"{type(exc).__name__}: {exc}".replace("\n", " ")
        nan = float("nan")
        return [Trial(controller, env_name, i, s, -1, False, nan, 0, nan, False, nan, nan, nan, error=msg,
                      anatomy=anatomy_name(conditions.anatomy)) for i, s in enumerate(seeds, start=first)], []
    return trial_records(env, ctrl, controller, seeds, keep_paths, first)


def _job(args):
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import torch

    torch.set_num_threads(1)
    return run_trials(*args)


def wilson(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson interval of a success rate (fractions)."""
    if n == 0:
        return math.nan, math.nan
    p = successes / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return centre - half, centre + half


def summarize(trials: list[Trial]) -> list[dict]:
    """Per cell: SR with CI, AE over successful and over all trials, forces, steps to success."""
    rows = []
    for key in dict.fromkeys((t.controller, t.env) for t in trials):
        ts = [t for t in trials if (t.controller, t.env) == key]
        err = next((t.error for t in ts if t.error), "")
        n, s = len(ts), sum(t.success for t in ts)
        lo, hi = wilson(s, n) if not err else (math.nan, math.nan)
        ok = [t for t in ts if t.success]

        def mean(xs):
            xs = [x for x in xs if not math.isnan(x)]
            return float(np.mean(xs)) if xs else math.nan

        def median(xs):
            xs = [x for x in xs if not math.isnan(x)]
            return float(np.median(xs)) if xs else math.nan

        paper = PAPER_RESULTS.get(key[0], {}).get(key[1], (math.nan, math.nan))
        rows.append({
            "controller": key[0], "env": key[1], "trials": n,
            "success_rate": math.nan if err else 100.0 * s / n, "sr_ci_low": 100 * lo, "sr_ci_high": 100 * hi,
            "ae_success_mm": mean([t.final_mm for t in ok]), "ae_all_mm": mean([t.final_mm for t in ts]),
            "mean_force_n": mean([t.mean_force_n for t in ts]), "peak_force_n": mean([t.peak_force_n for t in ts]),
            "max_peak_force_n": max((t.peak_force_n for t in ts), default=math.nan),
            "steps_to_success": mean([t.steps_to_success for t in ok]),
            "contact_share": mean([t.contact_share for t in ts]),
            "force_at_success_n": mean([t.force_at_end_n for t in ok]),
            "over_1n_share": mean([t.over_1n_share for t in ts]), "over_2n_share": mean([t.over_2n_share for t in ts]),
            "median_target_motion_mm": median([t.target_motion_mm for t in ts]),
            "median_duration_s": median([t.duration_s for t in ts]),
            "exits": sum(t.exited for t in ts),
            "paper_sr": paper[0], "paper_ae": paper[1], "error": err,
        })
    return rows


def target_classes() -> dict[int, str]:
    """Class of every candidate point in the committed reachability map (empty without the map)."""
    from mjendo import targets

    try:
        return {p["id"]: p["class"] for p in targets.read_map(targets.TARGETS_FILE)["points"]}
    except OSError:
        return {}


def per_target(trials: list[Trial]) -> list[dict]:
    """Success per cell, stomach and target, with the target's class in its stomach's reachability map."""
    groups: dict[tuple, list[Trial]] = {}
    for t in trials:
        groups.setdefault((t.controller, t.env, t.anatomy, t.target), []).append(t)
    return [{"controller": c, "env": e, "anatomy": a, "target": k, "class": ts[0].target_class,
             "trials": len(ts), "successes": sum(t.success for t in ts),
             "mean_final_mm": float(np.mean([t.final_mm for t in ts]))}
            for (c, e, a, k), ts in groups.items()]


def by_class(trials: list[Trial]) -> list[dict]:
    """Per cell, over the free and over the contact-aided targets of the map: success, the median step at
    which successes arrive, and the median final error of failures (is the trial's time the limit?)."""
    cells: dict[tuple, dict[str, list[Trial]]] = {}
    for t in trials:
        if t.target_class in ("free", "contact_aided") and not t.error:
            cells.setdefault((t.controller, t.env), {"free": [], "contact_aided": []})[t.target_class].append(t)

    def median(xs: list[float]) -> float:
        return float(np.median(xs)) if xs else float("nan")

    rows = []
    for (c, e), by in cells.items():
        row = {"controller": c, "env": e}
        for k, ts in by.items():
            row[f"{k}_trials"] = len(ts)
            row[f"{k}_sr"] = 100.0 * sum(t.success for t in ts) / len(ts) if ts else float("nan")
            row[f"{k}_success_step"] = median([t.steps_to_success for t in ts if t.success])
            row[f"{k}_miss_mm"] = median([t.final_mm for t in ts if not t.success])
        rows.append(row)
    return rows


def _fmt(x, nd=1):
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{nd}f}"


def _git_commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=paths.DATA, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def write_report(rows: list[dict], out: Path, command: str, wall_s: float, n: int,
                 conditions: Conditions = Conditions(), made: list | None = None, classes: list[dict] | None = None,
                 versions: tuple[int, ...] = (CURRENT_VERSION,)) -> Path:
    """report.md: ours next to the paper's tables, then every figure embedded with its caption.

    ``versions``: the task versions the controllers acted in, each with its own physics step in the fast stomachs.
    """
    steps = conditions.steps
    lines = [
        "# mjendo evaluation vs the paper",
        "",
        conditions.describe(versions),
        f"Command: `{command}`  ",
        f"Commit: `{_git_commit()}`, wall time {wall_s / 60:.1f} min, {n} trials per cell, {steps} steps each "
        f"(success: final tip error < {PAPER_SUCCESS_MM:g} mm).",
        "",
        "SR: success rate % (95 % Wilson interval). AE: average final error in mm over the *successful* "
        "trials (the paper's AE), and over all trials. Forces: mean over trials of the per-trial mean and "
        "peak resultant contact force.",
        "",
        "| policy | env | SR % (CI) | paper SR % | AE succ. mm | paper AE mm | AE all mm | mean F N | peak F N | "
        "steps to success | exits |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if r["error"]:
            lines.append(f"| {r['controller']} | {r['env']} | FAILED: {r['error'][:120]} |  |  |  |  |  |  |  |  |")
            continue
        lines.append(
            f"| {r['controller']} | {r['env']} | {_fmt(r['success_rate'])} ({_fmt(r['sr_ci_low'], 0)}-"
            f"{_fmt(r['sr_ci_high'], 0)}) | {_fmt(r['paper_sr'])} | {_fmt(r['ae_success_mm'], 2)} | "
            f"{_fmt(r['paper_ae'])} | {_fmt(r['ae_all_mm'], 1)} | {_fmt(r['mean_force_n'], 2)} | "
            f"{_fmt(r['peak_force_n'], 2)} | {_fmt(r['steps_to_success'], 1)} | {r['exits']} |")
    lines += ["", "## Contact reliance, safety and the moving wall", "",
              "Per trial, averaged over the cell: share of steps in contact; contact force at the last step of "
              "successful trials; share of steps above 1 N and above 2 N (CathSim's safety measure); median over "
              "trials of how far the target moved from its place at the trial's start, and of the trial's "
              "duration (simulated).", "",
              "| policy | env | in contact % | force at success N | > 1 N % | > 2 N % | target motion mm | "
              "duration s |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if not r["error"]:
            lines.append(
                f"| {r['controller']} | {r['env']} | {_fmt(100 * r['contact_share'])} | "
                f"{_fmt(r['force_at_success_n'], 2)} | {_fmt(100 * r['over_1n_share'], 2)} | "
                f"{_fmt(100 * r['over_2n_share'], 2)} | {_fmt(r['median_target_motion_mm'], 2)} | "
                f"{_fmt(r['median_duration_s'], 1)} |")
    if classes:
        lines += ["", "## Free and contact-aided targets", "",
                  "Success % over the trials that aimed at free targets (reached in free space) and at "
                  "contact-aided ones (10 mm or more beyond free-space reach, reached with the wall), by the "
                  "reachability map's classes (docs/task.md); trials in brackets. Success step: the median "
                  f"step (of {steps}) at which successful trials arrived; miss: the median final error of the "
                  "failed ones.", "",
                  "| policy | env | free SR % | success step | miss mm | contact-aided SR % | success step | "
                  "miss mm |", "|---|---|---|---|---|---|---|---|"]
        for r in classes:
            lines.append(" | ".join([f"| {r['controller']}", r["env"], *(
                f"{_fmt(r[f'{k}_sr'])} ({r[f'{k}_trials']}) | {_fmt(r[f'{k}_success_step'], 0)} | "
                f"{_fmt(r[f'{k}_miss_mm'])}" for k in ("free", "contact_aided"))]) + " |")
    if made:
        lines += ["", "## Figures", ""]
        for fig, text in made:
            lines += [f"![{text}]({Path(fig).name})", "", f"*{text}*", ""]
    path = out / "report.md"
    path.write_text("\n".join(lines) + "\n")
    return path


def _open(path: Path, mode: str) -> IO[str]:
    """Text of a CSV file, gzip-compressed when its name ends in .gz (mtime 0: same rows, same bytes)."""
    if path.suffix != ".gz":
        return open(path, mode, newline="")
    return io.TextIOWrapper(gzip.GzipFile(path, mode + "b", mtime=0), newline="")


def write_table(path: Path, rows: list[dict]) -> None:
    """CSV rows, compressed when the name ends in .gz (per-trial tables: 4x smaller in git); written whole
    or not at all."""
    tmp = path.with_name(path.name + ".partial" + (".gz" if path.suffix == ".gz" else ""))
    with _open(tmp, "w") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    os.replace(tmp, path)


def read_table(path: Path) -> list[dict]:
    """The rows of a table written by write_table (values as strings)."""
    with _open(path, "r") as f:
        return list(csv.DictReader(f))


def evaluate(trials: int = 200, controllers=CONTROLLERS, workers: int = 2, out: Path | None = None, seed: int = 0,
             command: str = "make eval", envs: tuple[str, ...] | None = None, overwrite: bool = False,
             **conditions) -> dict:
    """Every cell's trials; policies act in the task version they trained in, the baseline in ``version``.

    ``conditions``: the fields of Conditions (fidelity, version, anatomy, steps, randomization, timestep,
    contact_time_constant, force_off). ``steps`` longer than the paper's 80 measure what the trial's time costs:
    success by step 80 in them is the 80-step trial's, the trajectories being the same.
    """
    from tqdm import tqdm

    from mjendo.policies import version_of

    cond = Conditions(**conditions)
    if trials < 1 or workers < 1 or seed < 0:
        raise ConfigError(f"--trials and --workers must be >= 1 and --seed >= 0 (got {trials}, {workers}, {seed})")
    check_controllers(controllers)
    unknown = sorted(set(envs or ()) - set(CONDITIONS))
    if unknown:
        raise ConfigError(f"unknown environment(s) {', '.join(unknown)} in --envs; valid: {', '.join(CONDITIONS)}")
    study = [(c, e) for c, e in cells(controllers) if envs is None or e in envs]
    if not study:
        raise ConfigError(f"no trials: {', '.join(envs or ())} holds none of these policies' cells (FE only for "
                          "policies trained in free space, A; the others SE, DE, UE1, UE2)")
    cond.check(controllers)
    out = Path(out) if out is not None else default_out(cond.fidelity)
    guard_overwrite(out, trials, overwrite)
    out.mkdir(parents=True, exist_ok=True)
    chunk = max(1, math.ceil(trials / 4))
    jobs = []
    for c, e in study:
        seeds = [EVAL_SEED_BASE + seed * 100003 + i for i in range(trials)]
        for j in range(0, trials, chunk):
            keep = c == "E" and e == "DE" and j == 0
            jobs.append((c, e, seeds[j:j + chunk], keep, j, cond))
    t0 = time.time()
    all_trials, tip_paths = [], []
    with get_context("spawn").Pool(workers) as pool:
        for ts, ps in tqdm(pool.imap_unordered(_job, jobs), total=len(jobs), desc="evaluating", unit="chunk"):
            all_trials += ts
            tip_paths += ps
    order = {k: i for i, k in enumerate(study)}
    all_trials.sort(key=lambda t: (order[(t.controller, t.env)], t.trial))
    wall = time.time() - t0
    write_table(out / "trials.csv.gz", [asdict(t) for t in all_trials])
    rows = summarize(all_trials)
    write_table(out / "summary.csv", rows)
    write_table(out / "per_target.csv", per_target(all_trials))
    from mjendo import figures

    made = figures.all_figures(rows, tip_paths, out, [asdict(t) for t in all_trials], cond.steps)
    versions = tuple(sorted({version_of(c, cond.version) for c, _ in study}))
    report = write_report(rows, out, command, wall, trials, cond, made, by_class(all_trials), versions)
    print(report.read_text())
    print(f"wrote {out} in {wall / 60:.1f} min")
    return {"rows": rows, "wall_s": wall}


def randomization_arg(text: str):
    """--randomization: 'true', or a JSON object of config.Randomization fields (checked by the task)."""
    if text.strip().lower() == "true":
        return True
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise argparse.ArgumentTypeError(f"{text!r} is neither 'true' nor a JSON object ({exc.msg}); e.g. "
                                         "'{\"friction\": [0.2, 0.2]}'") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"{text!r} is not a JSON object of config.Randomization fields")
    return value


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m mjendo.evaluation", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trials", type=int, default=200,
                    help="trials per cell (200: 95%% CI about +-3 points at 95%% SR, +-7 at 50%%)")
    ap.add_argument("--policies", default=",".join(CONTROLLERS),
                    help="comma-separated: A-E (shipped), baseline, published variants (E-paper-step: "
                         "models/policies/variants/), or policy/run folders (runs/E/seed0)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--fidelity", choices=list(FIDELITIES), default="fast", help="stomach to evaluate in")
    ap.add_argument("--envs", help="comma-separated subset of FE, SE, DE, UE1, UE2 (default: all of the study)")
    ap.add_argument("--out", type=Path, help="results folder (default runs/eval/<fidelity>, untracked; the "
                    "committed study is eval/results)")
    ap.add_argument("--overwrite", action="store_true", help="replace a report made with more trials per cell")
    ap.add_argument("--version", type=int, default=CURRENT_VERSION, choices=sorted(VERSIONS),
                    help="task version of the baseline's trials (policies act in the version they trained in)")
    ap.add_argument("--trial-steps", type=int, default=PAPER_EVAL_STEPS,
                    help="trial length (the paper's 80; longer: what the trial's time costs)")
    ap.add_argument("--anatomy", type=targets.anatomy_arg,
                    help="other stomachs: a generated one's seed, a built folder, or a set (train, val, test, or "
                    "seeds of your own as 110-119: trials spread evenly over its stomachs)")
    ap.add_argument("--randomization", type=randomization_arg,
                    help="tissue, load, friction and sensor noise drawn per trial: 'true' for the ranges of "
                    "config.Randomization, or a JSON object of its fields, e.g. '{\"young_scale\": [0.33, 0.34]}'")
    ap.add_argument("--timestep", type=float, help="physics step in s instead of the stomach's own (full 0.01, "
                    "the fast ones 0.02): how much a policy's success depends on it")
    ap.add_argument("--contact-time-constant", type=float, help="time constant in s of the scope-wall contacts and "
                    "the fast stomachs' anchors instead of the scene's (0.02, 0.01; MuJoCo raises it to two physics "
                    "steps): how much a policy's success depends on the contact's softness (docs/physics.md)")
    ap.add_argument("--force-off", action="store_true", help="the force sensor reads nothing (contact 0, force 0) "
                    "while C and E keep their inputs: how much of what they do they draw from the force")
    a = ap.parse_args(argv)
    command = "python -m mjendo.evaluation " + " ".join(argv if argv is not None else sys.argv[1:])
    return cli.run(lambda: evaluate(a.trials, tuple(a.policies.split(",")), a.workers, a.out, a.seed, command=command,
                                    fidelity=a.fidelity, envs=tuple(a.envs.split(",")) if a.envs else None,
                                    overwrite=a.overwrite, version=a.version, anatomy=a.anatomy,
                                    steps=a.trial_steps, randomization=a.randomization, timestep=a.timestep,
                                    contact_time_constant=a.contact_time_constant, force_off=a.force_off),
                   ConfigError, PolicyError)


if __name__ == "__main__":
    raise SystemExit(main())
