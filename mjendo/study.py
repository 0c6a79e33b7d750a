"""``make study`` / ``python -m mjendo.study``: the paper's comparisons over several training seeds, on Ray.

Each (policy, seed) of the grid is one Ray task that trains the policy (or
resumes its run folder ``runs/<P>/seed<N>/`` from the last checkpoint, or
skips training when the run is finished) and then evaluates the final
policy in every environment of the study, writing ``study_trials.csv.gz``
into the run folder. A finished trial is not run again: killing the study
and running the same command resumes where it stopped. Tasks declare their
resources (``--cpus-per-trial``, ``--gpus-per-trial``); ``ray.init()``
starts a local cluster on a laptop, ``--address`` (or ``RAY_ADDRESS``)
connects to a running cluster. An entry is a policy letter or a variant of one
(``E-randomized``: train/policies.yaml's variants); ``--anatomy test`` evaluates
in the held-out anatomies instead of the built-in stomach.

The analysis (:mod:`mjendo.stats`) gives per policy and environment the
success rate with a 95 % interval over seeds and trials (stratified
bootstrap), mean error and force, and the paper's comparisons C - B, E - D,
E - C, D - B, E - A as differences with intervals. Writes ``summary.csv``,
``comparisons.csv``, ``report.md``, ``seeds.png`` and, per seed, its
``meta.json`` and trials, into ``--out`` (default ``runs/study``;
``eval/study`` is the committed study).
"""

from __future__ import annotations

import argparse
import filecmp
import json
import os
import shutil
import socket
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from mjendo import artifacts, cli, paths, scene, stats, targets
from mjendo.artifacts import PolicyError
from mjendo.config import (
    CONDITIONS,
    FIDELITIES,
    PAPER_EVAL_STEPS,
    POLICY_NAMES,
    ConfigError,
    TaskConfig,
    task_config,
)
from mjendo.evaluation import EVAL_SEED_BASE, Conditions, cells, read_table, run_trials, write_table
from mjendo.train_config import load as load_config

ADOPTED_MARK = "ADOPTED"  # a run folder copied from a published seed (its trials; its weights when published)
RESULTS_FILE = "study_trials.csv.gz"  # compressed (4x): every published seed carries its trials in git
VALIDATION_FILE = "study_validation.json"


def per_stomach(name: str, fidelity: str, anatomy: int | str | None = None, steps: int = PAPER_EVAL_STEPS) -> str:
    """A run's study file for one stomach: the fast built-in one keeps ``name``, others add their fidelity
    and the stomachs evaluated in (``study_trials_test.csv.gz``: the test anatomies), and trials of another
    length than the paper's add it (``study_trials_steps160.csv.gz``).

    So a full-stomach, test-anatomy or longer-trial study keeps its own cache and never overwrites the fast one's.
    """
    stem, ext = name.split(".", 1)
    tags = ([] if fidelity == "fast" else [fidelity]) + ([] if anatomy is None else [Path(str(anatomy)).name]) \
        + ([] if steps == PAPER_EVAL_STEPS else [f"steps{steps}"])
    return ".".join(["_".join([stem, *tags]), ext])


def results_file(cfg: StudyConfig) -> str:
    """The name of a run's study trials for this study's stomach and trial length."""
    return per_stomach(RESULTS_FILE, cfg.fidelity, cfg.anatomy, cfg.trial_steps)


def study_files(directory: Path) -> list[Path]:
    """Every stomach's study trials and validation in a folder (what publishing and adopting carry)."""
    stems = [f.split(".", 1)[0] for f in (RESULTS_FILE, VALIDATION_FILE)]
    return sorted(f for stem in stems for f in Path(directory).glob(f"{stem}*"))


def split_spec(spec: str) -> tuple[str, str | None]:
    """A study entry: a policy letter, or a variant of it as ``E-randomized`` (train/policies.yaml variants)."""
    policy, _, variant = spec.partition("-")
    return policy, variant or None


def policy_home(spec: str) -> Path:
    """Where an entry's shipped policy lives: models/policies/<P>/ (the letter's shipped recipe), another
    variant's models/policies/variants/<P>-<v>/."""
    letter, variant = split_spec(spec)
    return paths.policies_dir() / letter if variant is None else artifacts.home(letter, variant)


# Validation (choosing the seed to ship): trials in the policy's own training condition on seeds of their
# own, disjoint from the evaluation trials (30,000,000+) and from training's periodic evaluations (10,000,000+).
VALIDATION_SEED = 20_000_000
RUNNING_MARK = ".study_running"
# The paper's questions: force sensing (C - B trained static, E - D trained moving), training in the moving
# stomach (E - C with force sensing, D - B without) and contact use (E - A).
COMPARISONS = (("C", "B"), ("E", "D"), ("E", "C"), ("D", "B"), ("E", "A"))


@dataclass(frozen=True)
class StudyConfig:
    """One study grid and where it runs."""

    policies: tuple[str, ...] = ("D", "E")  # letters, or variants as E-randomized
    seeds: tuple[int, ...] = (0, 1, 2)
    # Per-policy seed lists that replace ``seeds`` for that policy (``--seeds-for D=0,1``): a study can hold
    # the seeds that have finished for each policy without training the missing ones of the others.
    seeds_for: tuple[tuple[str, tuple[int, ...]], ...] = ()
    timesteps: int | None = None  # None: each policy's budget in the training config
    trials: int = 200  # evaluation trials per environment and seed
    validation_trials: int = 100  # per seed, in the training condition: picks the seed to ship
    # Stomachs the validation trials run in instead of the training condition's (its env still): "val", disjoint
    # from the training and test stomachs, picks the seed that generalises without looking at the test set.
    validation_anatomy: int | str | None = None
    fidelity: str = "fast"  # stomach the final policies are evaluated in
    envs: tuple[str, ...] | None = None  # None: the evaluation study's environments
    anatomy: int | str | None = None  # stomachs evaluated in (TaskConfig.anatomy): None the built-in one
    trial_steps: int = PAPER_EVAL_STEPS  # evaluation trial length (longer: what the trial's time costs)
    config: Path = paths.TRAINING_CONFIG
    runs: Path = paths.RUNS
    out: Path = paths.RUNS / "study"
    cpus_per_trial: float = 1.0
    gpus_per_trial: float = 0.0
    address: str | None = None
    ship_best: bool = False  # ship each policy's best-by-validation seed, and publish every seed (publish())

    def seeds_of(self, policy: str) -> tuple[int, ...]:
        """The training seeds of one policy in this grid."""
        return dict(self.seeds_for).get(policy, self.seeds)

    def grid(self) -> list[tuple[str, int]]:
        """Every (policy, seed) of the study."""
        return [(p, s) for p in self.policies for s in self.seeds_of(p)]

    def check(self) -> None:
        bad = [p for p in self.policies if split_spec(p)[0] not in POLICY_NAMES]
        if bad or not self.policies:
            raise ConfigError(f"unknown policy {bad[0] if bad else ''!r}; valid: {', '.join(POLICY_NAMES)}, or a "
                              "variant of one as E-randomized")
        stray = [p for p, _ in self.seeds_for if p not in self.policies]
        if stray:
            raise ConfigError(f"--seeds-for names policy {stray[0]!r}, which is not in --policies "
                              f"{','.join(self.policies)}: add it there or drop its seeds")
        for seeds in (self.seeds, *(s for _, s in self.seeds_for)):
            if not seeds or min(seeds) < 0 or len(set(seeds)) != len(seeds):
                raise ConfigError(f"seeds must be distinct whole numbers >= 0, got {list(seeds)}")
        if self.trials < 1 or self.validation_trials < 1 or self.trial_steps < 1 \
                or (self.timesteps is not None and self.timesteps < 1):
            raise ConfigError("--trials, --validation-trials, --trial-steps and --timesteps must be >= 1")
        if self.cpus_per_trial <= 0 or self.gpus_per_trial < 0:
            raise ConfigError("--cpus-per-trial must be > 0 and --gpus-per-trial >= 0")
        for p in self.policies:
            train_config(self, p, 0)  # unknown variants and bad configs stop here, named
        unknown = sorted(set(self.envs or ()) - set(CONDITIONS))
        if unknown:
            raise ConfigError(f"unknown environment(s) {', '.join(unknown)} in --envs; valid: {', '.join(CONDITIONS)}")
        for where in (self.anatomy, self.validation_anatomy):
            if where is not None:
                task_config(anatomy=where)
                targets.require_maps(where)
        if self.validation_anatomy is not None and self.validation_anatomy == self.anatomy:
            raise ConfigError(f"--validation-anatomy {self.validation_anatomy} is the set the study evaluates in: "
                              "pick the seed on other stomachs (val) than those it reports (test)")


def train_config(cfg: StudyConfig, spec: str, seed: int):
    policy, variant = split_spec(spec)
    return load_config(policy, cfg.config, variant, seed=seed, total_timesteps=cfg.timesteps)


def run_folder(cfg: StudyConfig, policy: str, seed: int) -> Path:
    from mjendo.train import run_folder as folder

    return folder(train_config(cfg, policy, seed), cfg.runs, None)


def finished(run: Path, budget: int) -> bool:
    meta = artifacts.read_meta(run) if run.exists() else {}
    return (run / artifacts.MODEL_FILE).exists() and int(meta.get("timesteps", 0)) >= budget


def reportable(run: Path, budget: int) -> bool:
    """Whether a run's cached trials may be reported as they are: a finished run, or a published seed
    adopted without its weights (a variant's seed that nothing starts from: its trials are the record)."""
    meta = artifacts.read_meta(run) if (run / artifacts.META_FILE).exists() else {}
    return finished(run, budget) or ((run / ADOPTED_MARK).exists() and int(meta.get("timesteps", 0)) >= budget)


def started_from(cfg: StudyConfig) -> set[Path]:
    """The policy folders the training config's variants start from (their init_from), resolved."""
    import yaml

    raw = yaml.safe_load(Path(cfg.config).read_text()) or {}
    return {paths.data_path(b["init_from"]).resolve() for b in (raw.get("variants") or {}).values()
            if (b or {}).get("init_from")}


def seed_folder(spec: str, seed: int) -> Path:
    """Where a published study seed lives: its policy files and its study trials (``--ship-best``); the
    shipped seed's model files are those of the shipped policy (artifacts.model_home)."""
    return policy_home(spec) / artifacts.SEEDS_DIR / f"seed{seed}"


def _same_task(meta: dict, task: TaskConfig) -> bool:
    """Whether a policy's meta names this task; fields added to TaskConfig since it was trained take their
    defaults (a meta from before ``randomization`` existed trained without it)."""
    try:
        return task_config(**artifacts.trained_task(meta)) == task
    except (ConfigError, TypeError):
        return False


def adopt_shipped(cfg: StudyConfig, policy: str, seed: int) -> bool:
    """Use a committed policy as this seed's run when it is exactly that run (same seed, task and budget).

    Candidates: the seed's published folder (``models/policies/<P>/seeds/seed<N>/``, with its study
    trials, so a fresh clone re-reports the study without training or evaluating), then the shipped
    policy. The budget is the run's configured total_timesteps (the shipped one trained for 1M steps is
    not a 2k-step smoke-test run), and the policy it started from the run's init_from (a fine-tuned
    variant's; none for a policy trained from scratch, so a policy fine-tuned in the full stomach is not).
    """
    from mjendo.train import latest_checkpoint

    run, tc = run_folder(cfg, policy, seed), train_config(cfg, policy, seed)
    if run.exists() and (latest_checkpoint(run) is not None or (run / artifacts.MODEL_FILE).exists()):
        return False  # a run of its own (an empty folder, e.g. a start that failed, is not: else 1M steps again)
    for source in (seed_folder(policy, seed), policy_home(policy)):
        meta = artifacts.read_meta(source) if (source / artifacts.META_FILE).exists() else {}
        if meta.get("seed") != seed or meta.get("training", {}).get("total_timesteps") != tc.total_timesteps:
            continue
        if not _same_task(meta, tc.task_config()) or meta.get("init_from") != tc.init_from:
            continue  # a fine-tune is a variant's run only when it started where that variant starts
        run.mkdir(parents=True, exist_ok=True)
        for name in (artifacts.META_FILE, artifacts.CONFIG_FILE, artifacts.MODEL_FILE, artifacts.NORM_FILE,
                     *artifacts.LOG_FILES, *(f.name for f in study_files(source))):
            model_file = name in (artifacts.MODEL_FILE, artifacts.NORM_FILE)
            found = (artifacts.model_home(source) if model_file else source) / name
            if found.exists():
                shutil.copy2(found, run / name)
        (run / ADOPTED_MARK).write_text(f"copied from {source} by mjendo.study: that policy is this seed's run\n")
        return True
    return False


def publish(cfg: StudyConfig) -> None:
    """Ship each policy's best seed to models/policies/<P>/ (a variant's to models/policies/variants/<P>-<v>/)
    and every seed, with its study trials, to <that folder>/seeds/seed<N>/ (model without optimizer moments,
    normalisation, meta, config; the shipped seed's folder without model and normalisation, which are the
    shipped policy's). Other seeds that no variant starts from are only re-evaluated: a letter's keep the
    policy without its value function (artifacts.slim_copy ``actor_only``), a variant's only their trials (the
    weights stay in git history), so the tree stays small."""
    best, sources = best_seeds(cfg), started_from(cfg)
    for p in cfg.policies:
        variant = policy_home(p).parent.name == "variants"
        for seed in cfg.seeds_of(p):
            run = run_folder(cfg, p, seed)
            if not (run / artifacts.MODEL_FILE).exists():
                continue  # adopted from its published folder without weights: that folder is its record
            evaluated_only = seed != best[p][0] and seed_folder(p, seed).resolve() not in sources
            dest = artifacts.ship(run, split_spec(p)[0], seed_folder(p, seed), actor_only=evaluated_only)
            for f in [run / "evaluations.csv", *study_files(run)]:
                if f.exists():
                    shutil.copy2(f, dest / f.name)
            if variant and evaluated_only:
                for name in (artifacts.MODEL_FILE, artifacts.NORM_FILE):
                    (dest / name).unlink()
        artifacts.ship(run_folder(cfg, p, best[p][0]), split_spec(p)[0], policy_home(p))
        for name in (artifacts.MODEL_FILE, artifacts.NORM_FILE):  # in git once: artifacts.model_home finds them
            (seed_folder(p, best[p][0]) / name).unlink(missing_ok=True)


def eval_seeds(cfg: StudyConfig) -> list[int]:
    """The evaluation study's trial seeds (mjendo.evaluation, seed 0): never used for training or tuning."""
    return [EVAL_SEED_BASE + i for i in range(cfg.trials)]


def _cached_cells(run: Path, cfg: StudyConfig, policy: str) -> dict[str, list[dict]]:
    """A run's cached trials per environment that this study can report as they are: measured on this stomach,
    these scene files and target lists, with this many trials (the same seeds). A study over more environments
    than an earlier one evaluates only the new ones. Rows carry this study's name for the policy."""
    path = run / results_file(cfg)
    if not path.exists():
        return {}
    by_env: dict[str, list[dict]] = {}
    for r in read_table(path):
        by_env.setdefault(r["env"], []).append(r)
    model = task_key(cfg)
    return {e: [{**r, "controller": policy} for r in rows] for e, rows in by_env.items()
            if len(rows) == cfg.trials and all(r["fidelity"] == cfg.fidelity and r.get("model") == model for r in rows)}


def task_key(cfg: StudyConfig) -> str:
    """What cached trials were measured on: the scene files and the target lists (both fingerprinted), and
    for other stomachs their meshes and maps."""
    key = f"{scene.fingerprint(cfg.fidelity)}-{targets.fingerprint()}"
    if cfg.anatomy is None:
        return key
    import hashlib

    from mjendo import anatomy

    h = hashlib.sha256()
    for m in anatomy.members(cfg.anatomy):
        folder = anatomy.stomach_dir(m)
        h.update((folder / "stomach.json").read_bytes())
        h.update(json.dumps(targets.read_map(targets.map_path(folder)), sort_keys=True).encode())
    return f"{key}-{h.hexdigest()[:12]}"


def _cells(cfg: StudyConfig, policy: str) -> list[tuple[str, str]]:
    return [(policy, e) for _, e in cells((split_spec(policy)[0],)) if cfg.envs is None or e in cfg.envs]


def _all_cached(cfg: StudyConfig, policy: str, seed: int) -> bool:
    """Whether every cell this study asks of the seed is cached in a run that may report it as it is."""
    run = run_folder(cfg, policy, seed)
    cached = _cached_cells(run, cfg, policy)
    return all(e in cached for _, e in _cells(cfg, policy)) and \
        reportable(run, train_config(cfg, policy, seed).total_timesteps)


def will_train(cfg: StudyConfig, policy: str, seed: int) -> bool:
    """Whether the grid point trains: its cells are not all cached and its run has no finished weights (a seed
    published with its trials only, asked for other cells, trains again from its variant's start)."""
    return not _all_cached(cfg, policy, seed) and \
        not finished(run_folder(cfg, policy, seed), train_config(cfg, policy, seed).total_timesteps)


def trial(cfg: StudyConfig, policy: str, seed: int) -> list[dict]:
    """One grid point: train or resume (or skip when finished), then evaluate; returns the trial rows."""
    import torch

    from mjendo.train import train

    torch.set_num_threads(1)
    run = run_folder(cfg, policy, seed)
    cached, want = _cached_cells(run, cfg, policy), [e for _, e in _cells(cfg, policy)]
    if _all_cached(cfg, policy, seed):
        validate(cfg, policy, run)
        return [r for e in want for r in cached[e]]
    run.mkdir(parents=True, exist_ok=True)
    mark = run / RUNNING_MARK
    mark.write_text(f"{socket.gethostname()} {os.getpid()}\n")
    try:
        if not finished(run, train_config(cfg, policy, seed).total_timesteps):  # will_train: not all cached here
            cached = {}  # trials of the weights before this training are not this policy's
            letter, variant = split_spec(policy)
            train(letter, cfg.timesteps, seed, out=cfg.runs, config_file=cfg.config, progress=False,
                  variant=variant)
        rows, model = [], task_key(cfg)
        for env in want:
            if env in cached:
                rows += cached[env]
                continue
            trials, _ = run_trials(str(run), env, eval_seeds(cfg), conditions=Conditions(
                cfg.fidelity, anatomy=cfg.anatomy, steps=cfg.trial_steps))
            rows += [{**asdict(t), "controller": policy, "seed_trained": seed, "fidelity": cfg.fidelity,
                      "model": model} for t in trials]
        kept = [r for e, others in cached.items() if e not in want for r in others]  # other studies' cells stay
        write_table(run / results_file(cfg), rows + kept)
        validate(cfg, policy, run)
        return rows
    finally:
        mark.unlink(missing_ok=True)


def validate(cfg: StudyConfig, policy: str, run: Path) -> dict:
    """Success rate and mean error on the validation trials in the training condition, its stomachs included,
    or in ``cfg.validation_anatomy``'s stomachs (cached in the run)."""
    path = run / per_stomach(VALIDATION_FILE, cfg.fidelity, cfg.validation_anatomy)
    tc = train_config(cfg, policy, 0)
    where = tc.task_config().anatomy if cfg.validation_anatomy is None else cfg.validation_anatomy
    model = task_key(replace(cfg, anatomy=where))
    if path.exists():
        cached = json.loads(path.read_text())
        if (cached.get("fidelity"), cached.get("model"), cached.get("trials")) == (cfg.fidelity, model,
                                                                                   cfg.validation_trials):
            return cached
    if not (artifacts.model_home(run) / artifacts.MODEL_FILE).exists():
        raise ConfigError(f"{run} holds a published seed's trials without its weights, not the validation "
                          "trials this study asks for: study it with the validation trials it was published "
                          "with (--validation-trials), or delete the folder to train the seed again")
    seeds = [VALIDATION_SEED + i for i in range(cfg.validation_trials)]
    trials, _ = run_trials(str(run), tc.env, seeds, conditions=Conditions(cfg.fidelity, anatomy=where))
    result = {"env": tc.env, "fidelity": cfg.fidelity, "model": model, "trials": len(trials),
              "first_seed": VALIDATION_SEED,
              "success_rate": float(np.mean([t.success for t in trials])),
              "mean_final_mm": float(np.mean([t.final_mm for t in trials]))}
    path.write_text(json.dumps(result, indent=1) + "\n")
    return result


def best_seeds(cfg: StudyConfig) -> dict[str, tuple[int, dict]]:
    """Per policy, the seed with the best validation success rate (then the smaller error)."""
    best = {}
    for p in cfg.policies:
        scored = [(s, validate(cfg, p, run_folder(cfg, p, s))) for s in cfg.seeds_of(p)]
        best[p] = max(scored, key=lambda sv: (sv[1]["success_rate"], -sv[1]["mean_final_mm"]))
    return best


# ------------------------------------------------------------------ Ray
def _reachable(address: str) -> None:
    """Fail fast, naming the fix, when a cluster address cannot be reached (ray.init would wait a long time)."""
    if address in ("auto", "local"):
        return
    hostport = address.split("://", 1)[-1]
    host, _, port = hostport.rpartition(":")
    if not host or not port.isdigit():
        raise ConfigError(f"--address {address!r} is not host:port (e.g. 10.0.0.5:6379, or ray://10.0.0.5:10001)")
    try:
        with socket.create_connection((host, int(port)), timeout=5):
            pass
    except OSError as exc:
        raise ConfigError(f"cannot reach the Ray cluster at {address} ({exc.strerror or exc}): start it with "
                          "`ray start --head --port=6379` on the head node, or leave out --address to run "
                          "locally") from exc


def connect(address: str | None) -> None:
    try:
        import ray
    except ImportError as exc:
        raise ConfigError("the study runs on Ray: install it with `pip install 'mjendo[study]'` (make study "
                          "does)") from exc
    address = address or os.environ.get("RAY_ADDRESS")
    if address:
        _reachable(address)
    if ray.is_initialized():
        return
    os.environ.setdefault("RAY_AUTH_MODE", "disabled")  # a local throwaway cluster needs no token
    try:
        if address:
            ray.init(address=address, log_to_driver=False)
        else:
            ray.init(include_dashboard=False, log_to_driver=False)
    except Exception as exc:  # ConnectionError, RuntimeError, version mismatch
        raise ConfigError(f"cannot start or join Ray ({exc}); see docs/study.md") from exc


def _steps_done(cfg: StudyConfig, grid: list[tuple[str, int]]) -> int:
    total = 0
    for p, s in grid:
        path = run_folder(cfg, p, s) / "episodes.csv"
        if path.exists():
            with open(path, "rb") as f:
                f.seek(max(0, path.stat().st_size - 200))
                last = f.read().decode(errors="ignore").strip().splitlines()[-1]
            first = last.split(",")[0]
            total += int(first) if first.isdigit() else 0
    return total


def run_grid(cfg: StudyConfig) -> list[dict]:
    """Every grid point as a Ray task; progress every 15 s; returns all trial rows."""
    connect(cfg.address)  # first: without Ray it says how to install it
    import ray

    grid = cfg.grid()
    for p, s in grid:
        if not adopt_shipped(cfg, p, s):
            continue
        if will_train(cfg, p, s):
            print(f"{p} seed {s}: published with its trials only, not those this study asks for: trained again "
                  f"({train_config(cfg, p, s).total_timesteps:,} steps; its run, bit for bit on one machine kind)")
        else:
            print(f"{p} seed {s}: the shipped policy is this run (same seed, task and budget): not retrained")
    task = ray.remote(num_cpus=cfg.cpus_per_trial, num_gpus=cfg.gpus_per_trial)(trial)
    refs = {task.remote(cfg, p, s): (p, s) for p, s in grid}
    rows, pending = [], list(refs)
    t0, steps0 = time.time(), _steps_done(cfg, grid)
    last = t0
    while pending:
        ready, pending = ray.wait(pending, num_returns=1, timeout=15)
        for ref in ready:
            try:
                rows += ray.get(ref)
            except ray.exceptions.RayTaskError as exc:
                p, s = refs[ref]
                raise ConfigError(f"{p} seed {s} failed: {exc.cause if hasattr(exc, 'cause') else exc}") from exc
        if time.time() - last >= 15 or not pending:
            last = time.time()
            running = sum((run_folder(cfg, p, s) / RUNNING_MARK).exists() for p, s in grid)
            done = len(grid) - len(pending)
            rate = (_steps_done(cfg, grid) - steps0) / max(time.time() - t0, 1e-9)
            print(f"study: {done} done, {min(running, len(pending))} running, "
                  f"{len(pending) - min(running, len(pending))} pending; {rate:.0f} training steps/s", flush=True)
    return rows


# ------------------------------------------------------------------ analysis
def analyse(rows: list[dict]) -> tuple[list[dict], list[dict], dict]:
    """Per policy x env estimates over seeds and trials, and the paper's comparisons."""
    per_cell: dict[tuple[str, str], dict[int, list[dict]]] = {}
    for r in rows:
        per_cell.setdefault((r["controller"], r["env"]), {}).setdefault(int(r["seed_trained"]), []).append(r)
    # Cells in one fixed order, not the order Ray's tasks finished in: the bootstrap draws from one stream,
    # so the same trials give the same intervals on every run.
    per_cell = dict(sorted(per_cell.items(), key=lambda kv: (kv[0][0], list(CONDITIONS).index(kv[0][1]))))
    summary, estimates = [], {}
    rng = np.random.default_rng(0)  # one stream for all estimates: their replicates are independent
    for (pol, env), by_seed in per_cell.items():
        seeds = sorted(by_seed)
        success = [np.array([success_of(t) for t in by_seed[s]], float) for s in seeds]
        est = stats.estimate(success, rng)
        estimates[pol, env] = est
        err = stats.estimate([np.array([float(t["final_mm"]) for t in by_seed[s]]) for s in seeds], rng)
        force = stats.estimate([np.array([float(t["mean_force_n"]) for t in by_seed[s]]) for s in seeds], rng)
        summary.append({
            "policy": pol, "env": env, "seeds": len(seeds), "trials_per_seed": len(by_seed[seeds[0]]),
            "sr": 100 * est["mean"], "sr_low": 100 * est["low"], "sr_high": 100 * est["high"],
            "sr_per_seed": " ".join(f"{100 * s.mean():.1f}" for s in success),
            "error_mm": err["mean"], "error_low": err["low"], "error_high": err["high"],
            "mean_force_n": force["mean"], "seed_list": " ".join(map(str, seeds)),
        })
    comparisons = []
    names = dict.fromkeys(c for c, _ in per_cell)
    variants = [(c, split_spec(c)[0]) for c in names if split_spec(c)[1]]
    # The paper's questions asked again of two policies trained by the same variant (E-guided - D-guided).
    recipes = dict.fromkeys(split_spec(c)[1] for c, _ in variants)
    same_recipe = [(f"{a}-{v}", f"{b}-{v}") for a, b in COMPARISONS for v in recipes
                   if f"{a}-{v}" in names and f"{b}-{v}" in names]
    # A variant against its policy says what its change bought.
    # A letter the study holds only as one policy, asked the paper's question of the other's recipe (D-paper - B).
    held = {}
    for c in names:
        held.setdefault(split_spec(c)[0], []).append(c)
    mixed = [(x, y) for a, b in COMPARISONS for v in recipes
             for x, y, only in ((f"{a}-{v}", b, b), (a, f"{b}-{v}", a))
             if x in names and y in names and held[only] == [only]]
    for a, b in (*COMPARISONS, *same_recipe, *variants, *mixed):
        for env in CONDITIONS:
            if (a, env) in estimates and (b, env) in estimates:
                d = stats.difference(estimates[a, env], estimates[b, env])
                lo, hi = over_targets(per_cell[a, env], per_cell[b, env], rng)
                comparisons.append({"comparison": f"{a} - {b}", "env": env, "diff_points": 100 * d["mean"],
                                    "low": 100 * d["low"], "high": 100 * d["high"],
                                    "supported": d["excludes_zero"], "low_targets": lo, "high_targets": hi,
                                    "supported_targets": bool(lo > 0 or hi < 0)})
    if any(_stomachs([_target(t)]) for by_seed in per_cell.values() for ts in by_seed.values() for t in ts[:1]):
        spread = np.random.default_rng(1)  # its own stream: the intervals above stay as they were
        for row, by_seed in zip(summary, per_cell.values(), strict=True):
            row["sr_low_stomachs"], row["sr_high_stomachs"] = over_stomachs(by_seed, spread)
    return summary, comparisons, {k: v for k, v in per_cell.items()}


def over_targets(a: dict[int, list[dict]], b: dict[int, list[dict]], rng) -> tuple[float, float]:
    """95 % interval (points) of a - b resampling training seeds and targets (the targets both were tried on),
    and in a set of stomachs the stomachs too.

    The generalisation question asks about other targets as much as other seeds: each replicate draws the
    targets once for both policies and each policy's seeds independently (stats.crossed).
    """
    common = sorted({_target(t) for ts in a.values() for t in ts} & {_target(t) for ts in b.values() for t in ts})
    ta, tb = _target_table(a, common), _target_table(b, common)
    keep = ~(np.isnan(ta).any(0) | np.isnan(tb).any(0))  # targets every seed of both was tried on
    if not keep.any():
        return float("nan"), float("nan")
    kept = [common[i] for i in np.flatnonzero(keep)]
    ra, rb = stats.crossed([ta[:, keep], tb[:, keep]], rng=rng, groups=_stomachs(kept))
    lo, hi = stats.interval(ra - rb)
    return 100 * lo, 100 * hi


def _target_table(by_seed: dict[int, list[dict]], targets: list) -> np.ndarray:
    """(seeds, targets): each training seed's success rate on each target (NaN where it was not tried)."""
    return np.array([[np.mean([success_of(t) for t in by_seed[s] if _target(t) == k] or [np.nan])
                      for k in targets] for s in sorted(by_seed)])


def _stomachs(targets: list[tuple[str, int]]) -> list[str] | None:
    """Each target's stomach, to resample stomachs as well; None for the built-in stomach alone."""
    labels = [stomach for stomach, _ in targets]
    return labels if any(labels) else None


def over_stomachs(by_seed: dict[int, list[dict]], rng) -> tuple[float, float]:
    """95 % interval (points) of a policy's success in a set of stomachs, resampling training seeds, the
    stomachs and each stomach's targets (the targets every seed was tried on)."""
    targets = sorted({_target(t) for ts in by_seed.values() for t in ts})
    table = _target_table(by_seed, targets)
    keep = ~np.isnan(table).any(0)
    reps, = stats.crossed([table[:, keep]], rng=rng, groups=_stomachs([targets[i] for i in np.flatnonzero(keep)]))
    lo, hi = stats.interval(reps)
    return 100 * lo, 100 * hi


def _target(trial: dict) -> tuple[str, int]:
    """A trial's target: its stomach ("" the built-in one) and its point there. Cached rows come from CSV
    (strings), fresh ones from the evaluation (ints): compared as ints."""
    return str(trial.get("anatomy") or ""), int(trial["target"])


def _class(trial: dict, classes: dict[int, str]) -> str:
    """A trial's target class: recorded with the trial (its stomach's map), else the built-in map's."""
    return trial.get("target_class") or classes.get(int(trial["target"]), "")


def _column(trials: list[dict], name: str) -> np.ndarray:
    return np.array([float(t[name]) for t in trials], float)


def _class_sr(trials: list[dict], classes: dict[int, str], cls: str) -> float:
    hit = [success_of(t) for t in trials if _class(t, classes) == cls]
    return 100.0 * float(np.mean(hit)) if hit else float("nan")


def contact_and_motion(per_cell: dict) -> list[dict]:
    """Per policy x env, pooled over seeds: success on free and contact-aided targets, how far the target
    moved and how long a trial lasted (medians), contact share, steps above 1 N and 2 N, peak force."""
    from mjendo.evaluation import target_classes

    classes, out = target_classes(), []
    for (pol, env), by_seed in per_cell.items():
        ts = [t for s in sorted(by_seed) for t in by_seed[s]]
        out.append({"policy": pol, "env": env, "trials": len(ts), "free_sr": _class_sr(ts, classes, "free"),
                    "contact_aided_sr": _class_sr(ts, classes, "contact_aided"),
                    "median_target_motion_mm": float(np.nanmedian(_column(ts, "target_motion_mm"))),
                    "median_duration_s": float(np.nanmedian(_column(ts, "duration_s"))),
                    "contact_share_pct": 100 * float(np.nanmean(_column(ts, "contact_share"))),
                    "over_1n_pct": 100 * float(np.nanmean(_column(ts, "over_1n_share"))),
                    "over_2n_pct": 100 * float(np.nanmean(_column(ts, "over_2n_share"))),
                    "median_peak_force_n": float(np.nanmedian(_column(ts, "peak_force_n")))})
    return out


def per_target_rows(per_cell: dict) -> list[dict]:
    """Success per policy, env and target, pooled over seeds (the target's class from the map)."""
    from mjendo.evaluation import target_classes

    classes, out = target_classes(), []
    for (pol, env), by_seed in per_cell.items():
        groups: dict[tuple[str, int], list[dict]] = {}
        for s in sorted(by_seed):
            for t in by_seed[s]:
                groups.setdefault(_target(t), []).append(t)
        out += [{"policy": pol, "env": env, **({"anatomy": a} if a else {}), "target": k,
                 "class": _class(ts[0], classes), "trials": len(ts),
                 "success_pct": 100.0 * np.mean([success_of(t) for t in ts])}
                for (a, k), ts in sorted(groups.items())]
    return out


def per_stomach_rows(per_cell: dict) -> list[dict]:
    """Success per policy, env and stomach of a set, pooled over seeds (none for the built-in stomach)."""
    out = []
    for (pol, env), by_seed in per_cell.items():
        groups: dict[str, list[bool]] = {}
        for t in (t for s in sorted(by_seed) for t in by_seed[s] if t.get("anatomy") not in (None, "")):
            groups.setdefault(str(t["anatomy"]), []).append(success_of(t))
        order = sorted(groups, key=lambda a: (not a.isdigit(), int(a) if a.isdigit() else 0, a))  # seeds by number
        out += [{"policy": pol, "env": env, "anatomy": a, "trials": len(groups[a]),
                 "success_pct": 100.0 * np.mean(groups[a])} for a in order]
    return out


def success_of(trial: dict) -> bool:
    """A trial's outcome, from a fresh evaluation (bool) or a cached table (the string "True")."""
    return trial["success"] is True or str(trial["success"]) == "True"


def _csv(path: Path, rows: list[dict]) -> None:
    if rows:
        write_table(path, rows)


def seed_record(cfg: StudyConfig, policy: str, seed: int) -> Path:
    """The folder holding a seed's meta, study trials, validation and curve for the report: its published
    folder when that holds these very trials (in git once), else a copy under <out>/seeds/."""
    run, published = run_folder(cfg, policy, seed), seed_folder(policy, seed)
    names = (artifacts.META_FILE, results_file(cfg), per_stomach(VALIDATION_FILE, cfg.fidelity), "evaluations.csv")
    copy = Path(cfg.out) / "seeds" / f"{policy}_seed{seed}"
    def same(name: str) -> bool:  # both absent, or both there byte for byte
        a, b = run / name, published / name
        return a.exists() == b.exists() and (not a.exists() or filecmp.cmp(a, b, shallow=False))

    if (published / results_file(cfg)).exists() and all(same(n) for n in names[1:]):
        shutil.rmtree(copy, ignore_errors=True)  # an earlier report's copy of what is now published
        return published
    copy.mkdir(parents=True, exist_ok=True)
    for name in names:
        if (run / name).exists():
            shutil.copy2(run / name, copy / name)
    return copy


def _shown(folder: Path) -> str:
    """A folder as the report names it: relative to the repository when inside it."""
    try:
        return folder.resolve().relative_to(paths.WORK).as_posix()
    except ValueError:
        return folder.as_posix()


def write_outputs(cfg: StudyConfig, rows: list[dict], command: str, wall_s: float) -> Path:
    from mjendo import figures

    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    summary, comparisons, per_cell = analyse(rows)
    _csv(out / "summary.csv", summary)
    _csv(out / "comparisons.csv", comparisons)
    contact = contact_and_motion(per_cell)
    _csv(out / "contact_and_motion.csv", contact)
    _csv(out / "per_target.csv", per_target_rows(per_cell))
    if cfg.ship_best:
        publish(cfg)
    grid = sorted({(r["controller"], int(r["seed_trained"])) for r in rows})
    records = {(p, s): seed_record(cfg, p, s) for p, s in grid}
    fig = figures.study_seeds(summary, out / "seeds.png")
    curves = figures.study_curves({p: [records[q, s] for q, s in grid if q == p]
                                   for p in dict.fromkeys(q for q, _ in grid)}, out / "curves.png")
    lines = [
        "# mjendo study: the paper's comparisons over training seeds", "",
        f"Command: `{command}`  ",
        f"Wall time {wall_s / 60:.1f} min. Training seeds "
        f"{'; '.join(p + ' ' + ', '.join(map(str, cfg.seeds_of(p))) for p in cfg.policies)}, {cfg.trials} "
        f"evaluation trials ({cfg.trial_steps} steps, seeds 0-{cfg.trials - 1}) per "
        f"environment and seed, evaluated in the {cfg.fidelity} stomach"
        + ("." if cfg.anatomy is None else f"s of anatomy `{cfg.anatomy}` (trials spread evenly over its stomachs; "
           "a target is a point of one stomach)."), "",
        "SR: mean over seeds of each seed's success rate; 95 % interval from a stratified bootstrap over seeds and "
        "trials (mjendo/stats.py). Error: final tip error over all trials (mm).", "",
        "| policy | env | seeds | SR % (95 % CI) | SR per seed % | error mm (CI) | mean force N |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in summary:
        lines.append(f"| {r['policy']} | {r['env']} | {r['seeds']} | {r['sr']:.1f} ({r['sr_low']:.1f}-"
                     f"{r['sr_high']:.1f}) | {r['sr_per_seed']} | {r['error_mm']:.1f} ({r['error_low']:.1f}-"
                     f"{r['error_high']:.1f}) | {r['mean_force_n']:.2f} |")
    lines += ["", "## Contact and motion", "",
              "Pooled over seeds. SR over the map's free and contact-aided targets; the target's motion during a "
              "trial (farthest from where it was at the start) and the trial's simulated duration are medians; "
              "contact and force shares are of steps; peak force is the median over trials. Success per target: "
              "per_target.csv.", "",
              "| policy | env | SR free % | SR contact-aided % | target motion mm | trial s | steps in contact % "
              "| steps > 1 N % | steps > 2 N % | peak force N |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in contact:
        lines.append(f"| {r['policy']} | {r['env']} | {r['free_sr']:.1f} | {r['contact_aided_sr']:.1f} | "
                     f"{r['median_target_motion_mm']:.1f} | {r['median_duration_s']:.1f} | "
                     f"{r['contact_share_pct']:.1f} | {r['over_1n_pct']:.2f} | {r['over_2n_pct']:.2f} | "
                     f"{r['median_peak_force_n']:.2f} |")
    stomachs = per_stomach_rows(per_cell)
    if stomachs:
        _csv(out / "per_anatomy.csv", stomachs)
        names = list(dict.fromkeys(r["anatomy"] for r in stomachs))
        spread = {(r["policy"], r["env"]): r for r in summary}
        lines += ["", "## Per stomach", "", "Success % in each stomach, pooled over seeds (per_anatomy.csv), and in "
                  "all of them with the 95 % interval over seeds, stomachs and targets (a cluster bootstrap: the "
                  "stomachs drawn with replacement, then each drawn stomach's targets; summary.csv's "
                  "sr_low_stomachs and sr_high_stomachs): what another draw of stomachs may give.", "",
                  "| policy | env | all (95 % CI) | " + " | ".join(names) + " |", "|---|---|---|" + "---|" * len(names)]
        for pol, env in dict.fromkeys((r["policy"], r["env"]) for r in stomachs):
            sr = {r["anatomy"]: r["success_pct"] for r in stomachs if (r["policy"], r["env"]) == (pol, env)}
            row = spread[pol, env]
            lines.append(f"| {pol} | {env} | {row['sr']:.1f} ({row['sr_low_stomachs']:.1f}-"
                         f"{row['sr_high_stomachs']:.1f}) | " + " | ".join(f"{sr[a]:.0f}" for a in names) + " |")
    if comparisons:
        lines += ["", "## The paper's comparisons", "",
                  "| comparison | env | difference, points | 95 % CI over seeds and trials | excludes 0 | "
                  f"95 % CI over seeds{' and' if cfg.anatomy is None else ', stomachs and'} targets | excludes 0 |",
                  "|---|---|---|---|---|---|---|"]
        for c in comparisons:
            lines.append(f"| {c['comparison']} | {c['env']} | {c['diff_points']:+.1f} | {c['low']:+.1f} to "
                         f"{c['high']:+.1f} | {'yes' if c['supported'] else 'no'} | {c['low_targets']:+.1f} to "
                         f"{c['high_targets']:+.1f} | {'yes' if c['supported_targets'] else 'no'} |")
        lines += ["", "Only differences whose interval excludes 0 are claimed; the others are not distinguishable "
                  "with these seeds and trials."]
    best = best_seeds(cfg)
    lines += ["", "## Validation: which seed is shipped", "",
              f"{cfg.validation_trials} trials per seed in the policy's training condition"
              + ("" if cfg.validation_anatomy is None else f" (its env) in anatomy `{cfg.validation_anatomy}`")
              + ", on seeds "
              f"{VALIDATION_SEED}.. (disjoint from the evaluation trials above).", "",
              "| policy | seed | validation SR % | final error mm | best |", "|---|---|---|---|---|"]
    for p in cfg.policies:
        for seed in cfg.seeds_of(p):
            v = validate(cfg, p, run_folder(cfg, p, seed))
            mark = ("shipped" if cfg.ship_best else "yes") if best[p][0] == seed else ""
            lines.append(f"| {p} | {seed} | {100 * v['success_rate']:.1f} | {v['mean_final_mm']:.1f} | {mark} |")
    where = dict.fromkeys(_shown(records[g].parent) for g in grid)
    lines += ["", "Each seed's meta, trials, validation and training curve: "
              + ", ".join(f"`{w}/`" for w in where) + "."]
    lines += ["", f"![Success rate per seed (dots) and across seeds (bar, 95 % CI)]({fig.name})", "",
              "*Success rate of every training seed (dots) and the mean over seeds with its 95 % stratified-"
              "bootstrap interval (black), per environment.*", "",
              f"![Periodic evaluation of every seed during training]({curves.name})", "",
              "*Periodic evaluation during training (40 trials in the training condition at each run's "
              "eval_every, mean of three), every seed (evaluations.csv of each run).*", ""]
    (out / "report.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(f"wrote {out}")
    return out


def study(cfg: StudyConfig, command: str = "make study") -> Path:
    cfg.check()
    t0 = time.time()
    rows = run_grid(cfg)
    return write_outputs(cfg, rows, command, time.time() - t0)


def _ints(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated whole numbers, got {text!r}") from None


def _policy_seeds(text: str) -> tuple[str, tuple[int, ...]]:
    policy, sep, seeds = text.partition("=")
    if not sep or split_spec(policy)[0] not in POLICY_NAMES:
        raise argparse.ArgumentTypeError(f"expected POLICY=SEEDS such as D=0,1 (policy one of "
                                         f"{', '.join(POLICY_NAMES)}, or a variant as E-randomized), got {text!r}")
    return policy, _ints(seeds)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m mjendo.study", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--policies", default="D,E", help="comma-separated, A-E (default D,E), or variants of them "
                    "(train/policies.yaml) as E-randomized")
    ap.add_argument("--seeds", type=_ints, default=(0, 1, 2), help="comma-separated training seeds (default 0,1,2)")
    ap.add_argument("--seeds-for", type=_policy_seeds, action="append", default=[], metavar="P=SEEDS",
                    help="one policy's own seeds, e.g. D=0,1 (repeatable; the others use --seeds)")
    ap.add_argument("--timesteps", type=int, help="training budget per run (default: the config's)")
    ap.add_argument("--trials", type=int, default=200, help="evaluation trials per environment and seed")
    ap.add_argument("--validation-trials", type=int, default=100,
                    help="trials per seed in the training condition that pick the seed to ship")
    ap.add_argument("--validation-anatomy", type=targets.anatomy_arg,
                    help="run the validation trials in these stomachs (val: disjoint from training and test)")
    ap.add_argument("--fidelity", choices=list(FIDELITIES), default="fast", help="stomach to evaluate in")
    ap.add_argument("--envs", help="comma-separated subset of FE, SE, DE, UE1, UE2")
    ap.add_argument("--anatomy", type=targets.anatomy_arg,
                    help="evaluate in other stomachs: a set (test: the held-out anatomies; or seeds of "
                         "your own as 110-119), a seed or a folder")
    ap.add_argument("--trial-steps", type=int, default=PAPER_EVAL_STEPS,
                    help="evaluation trial length (the paper's 80; longer: what the trial's time costs; validation "
                    "trials stay at 80)")
    ap.add_argument("--config", type=Path, default=paths.TRAINING_CONFIG, help="training config")
    ap.add_argument("--runs", type=Path, default=paths.RUNS, help="run folders (shared storage on a cluster)")
    ap.add_argument("--out", type=Path, default=paths.RUNS / "study", help="results (eval/study: the committed one)")
    ap.add_argument("--cpus-per-trial", type=float, default=1.0)
    ap.add_argument("--gpus-per-trial", type=float, default=0.0)
    ap.add_argument("--address", help="Ray cluster (host:port or ray://host:10001); default: RAY_ADDRESS, else local")
    ap.add_argument("--ship-best", action="store_true",
                    help="copy each policy's best-by-validation seed to models/policies/<P>/ and every seed, "
                         "with its study trials, to models/policies/<P>/seeds/seed<N>/")
    a = ap.parse_args(argv)
    cfg = StudyConfig(policies=tuple(a.policies.split(",")), seeds=a.seeds, seeds_for=tuple(a.seeds_for),
                      timesteps=a.timesteps,
                      trials=a.trials, validation_trials=a.validation_trials,
                      validation_anatomy=a.validation_anatomy, fidelity=a.fidelity,
                      envs=tuple(a.envs.split(",")) if a.envs else None, anatomy=a.anatomy,
                      trial_steps=a.trial_steps, config=a.config,
                      runs=a.runs, out=a.out,
                      cpus_per_trial=a.cpus_per_trial, gpus_per_trial=a.gpus_per_trial, address=a.address,
                      ship_best=a.ship_best)
    command = "python -m mjendo.study " + " ".join(argv if argv is not None else sys.argv[1:])
    return cli.run(lambda: study(cfg, command), ConfigError, PolicyError)


if __name__ == "__main__":
    raise SystemExit(main())
