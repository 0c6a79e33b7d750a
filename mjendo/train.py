"""Train the paper's policies with PPO: ``python -m mjendo.train --policy E`` (or ``make train POLICY=E``).

A run lives in ``runs/<policy>/seed<N>/``: the resolved config, episodes.csv
(every training episode), evaluations.csv (periodic 80-step evaluation:
success rate, mean final error), TensorBoard logs, checkpoints and, at the
end, the policy folder files (:mod:`mjendo.artifacts`). Running the same
command again resumes from the last checkpoint; ``--ship`` (``make ship``)
copies a finished run's policy to ``models/policies/<policy>/``.
"""

from __future__ import annotations

import argparse
import csv
import os
import re
import shlex
import shutil
import signal
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import yaml

from mjendo import anatomy, artifacts, cli, paths, targets
from mjendo.artifacts import MODEL_FILE, NORM_FILE, PolicyError, model_home
from mjendo.config import FIDELITIES, PAPER_EVAL_STEPS, PAPER_SUCCESS_MM, ConfigError, default_target_list
from mjendo.sampling import TargetSampler
from mjendo.task import OBS_OPTIONS, obs_options
from mjendo.train_config import TrainConfig, from_dict
from mjendo.train_config import load as load_config

CKPT_DIR = "checkpoints"
BEST_DIR = "best"
CKPT_RE = re.compile(r"model_(\d+)\.zip")
# Seeds of the periodic evaluations during training: far from the evaluation study's (0, 1, ...), so
# picking best/ never looks at the trials that are reported.
TRAINING_EVAL_SEED = 10_000_000


def make_env(cfg: TrainConfig, rank: int, max_steps: int | None = None):
    """A thunk building one monitored training (or evaluation) environment of the run's task."""
    task = cfg.task_config()

    def thunk():
        import torch
        from stable_baselines3.common.monitor import Monitor

        from mjendo.envs import EndoscopeEnv

        torch.set_num_threads(1)
        kw = {**asdict(task), "max_steps": max_steps or task.max_steps}
        if rank < cfg.full_envs:  # the run's first full_envs environments sample the model of record
            kw["fidelity"] = "full"
        if cfg.train_targets:  # training draws from its own pool; periodic evaluations keep the env's list
            kw["target_list"] = cfg.train_targets
        env = EndoscopeEnv(**kw)
        if cfg.guide_steps:  # training's episodes (the periodic evaluation builds its own environment)
            from mjendo.demonstrations import GuidedStarts

            env = GuidedStarts(env)
        env = Monitor(env, info_keywords=("is_success", "distance_mm"))
        env.reset(seed=cfg.seed * 1000 + rank)
        return env

    return thunk


class _Appender:
    """A CSV log that survives a kill: opened for appending, flushed every row."""

    def __init__(self, path: Path, header: list[str]):
        new = not path.exists() or path.stat().st_size == 0  # a run killed before its first row left it empty
        self.f = open(path, "a", newline="")  # noqa: SIM115 (kept open for the run)
        self.w = csv.writer(self.f)
        if new:
            self.writerow(header)

    def writerow(self, row) -> None:
        self.w.writerow(row)
        self.f.flush()

    def close(self) -> None:
        self.f.close()


def trial_env_kwargs(cfg: TrainConfig) -> dict:
    """The periodic evaluation's task: the run's, as a trial (80 steps, success at the paper's distance
    whatever margin training asks)."""
    return {**asdict(cfg.task_config()), "max_steps": PAPER_EVAL_STEPS, "success_mm": PAPER_SUCCESS_MM}


def periodic_evaluation(model, venv, cfg: TrainConfig, meta: dict) -> tuple[float, float, float]:
    """Deterministic 80-step trials of the current policy: success rate, mean final error (mm), mean return."""
    from mjendo.envs import EndoscopeEnv
    from mjendo.policies import PPOController
    from mjendo.rollout import run

    env = EndoscopeEnv(**trial_env_kwargs(cfg))
    ctrl = PPOController.from_training(model, venv, meta)
    results = [run(env, ctrl, seed=TRAINING_EVAL_SEED + cfg.seed * 1000 + i) for i in range(cfg.eval_episodes)]
    env.close()
    succ = [float(info["is_success"]) for info, _ in results]
    err = [float(info["distance_mm"]) for info, _ in results]
    return float(np.mean(succ)), float(np.mean(err)), float(np.mean([r for _, r in results]))


def target_sampler(cfg: TrainConfig, run: Path | None = None) -> TargetSampler:
    """The run's target sampler (TrainConfig.target_sampling), with the solve rates of its latest checkpoint."""
    task = cfg.task_config()
    name = cfg.train_targets or task.target_list or default_target_list(task.env, task.version)
    members = anatomy.members(task.anatomy)
    keys, hard, base, sizes = [], [], [], []
    for member in members:
        table = targets.load(task.version, targets.map_path(anatomy.stomach_dir(member), task.version))
        listed = table.listed(name)
        keys += listed if len(members) == 1 else [(member, t) for t in listed]
        hard.append(table.contact_aided(listed))
        w = np.asarray(table.pool_weights(name), float)
        base.append(w if len(members) == 1 else w / w.sum())  # across a set: each stomach as often as the others
        sizes.append(len(listed))
    sampler = TargetSampler(keys, np.concatenate(hard), cfg.target_sampling, cfg.curriculum_steps,
                            base=np.concatenate(base), sizes=sizes if len(members) > 1 else None)
    ckpt = latest_checkpoint(run) if run is not None else None
    if ckpt is not None:
        sampler.load(ckpt.parent / f"sampling_{CKPT_RE.fullmatch(ckpt.name).group(1)}.json")
    return sampler


def _callbacks(cfg: TrainConfig, run: Path, meta: dict, start_steps: int, progress: bool = True):
    from stable_baselines3.common.callbacks import BaseCallback
    from tqdm import tqdm

    class Training(BaseCallback):
        """Episode log, periodic evaluation, checkpoints and a progress bar."""

        def __init__(self):
            super().__init__()
            self.episodes = _Appender(run / "episodes.csv", ["timesteps", "reward", "length", "success", "final_mm"])
            self.evals = _Appender(run / "evaluations.csv", ["timesteps", "success_rate", "mean_final_mm",
                                                             "mean_reward", "wall_s"])
            self.next_eval = (start_steps // cfg.eval_every + 1) * cfg.eval_every
            self.next_ckpt = (start_steps // cfg.checkpoint_every + 1) * cfg.checkpoint_every
            self.bar = tqdm(total=cfg.total_timesteps, initial=start_steps, unit="step", desc=f"policy {cfg.policy}",
                            dynamic_ncols=True, mininterval=2.0, file=sys.stdout, disable=not progress)
            self.t0, self.s0 = time.time(), start_steps
            self.recent: list[float] = []
            self.last_eval: float | None = None
            self.best = _best_so_far(run)
            self.sampler = target_sampler(cfg, run)

        def checkpoint_if_due(self) -> None:
            # Called between PPO updates only, so a resumed run keeps the uninterrupted run's step grid.
            if self.num_timesteps >= self.next_ckpt:
                self.next_ckpt = (self.num_timesteps // cfg.checkpoint_every + 1) * cfg.checkpoint_every
                save_checkpoint(self.model, run, self.sampler)

        def _on_rollout_start(self) -> None:
            self.checkpoint_if_due()
            if cfg.critic_warmup_steps:  # the update after this rollout trains the actor only once warmed up
                set_actor_trainable(self.model.policy, self.num_timesteps >= cfg.critic_warmup_steps)
            if self.sampler.active:  # how often each target is drawn (TrainConfig.target_sampling, curriculum)
                self.training_env.env_method("set_target_weights", self.sampler.env_weights(self.num_timesteps))
            if cfg.guide_steps:  # guided starts (mjendo.demonstrations): the most demonstrator steps, falling to 0
                self.training_env.env_method("set_guide_steps", guide_limit(cfg, self.num_timesteps))

        def _on_step(self) -> bool:
            for info in self.locals["infos"]:
                ep = info.get("episode")
                if ep is not None:
                    self.episodes.writerow([self.num_timesteps, ep["r"], ep["l"], int(info["is_success"]),
                                            info["distance_mm"]])
                    self.recent = (self.recent + [float(info["is_success"])])[-100:]
                    self.sampler.record(self.sampler.key(info), bool(info["is_success"]), int(ep["l"]))
            self.bar.update(self.model.n_envs)
            if self.num_timesteps >= self.next_eval:
                self.next_eval += cfg.eval_every
                self.evaluate()
            if self.n_calls % 50 == 0:
                rate = (self.num_timesteps - self.s0) / max(time.time() - self.t0, 1e-9)
                shown = {"steps_s": f"{rate:.0f}", "success": f"{np.mean(self.recent or [0]):.2f}"}
                if self.last_eval is not None:  # before the first evaluation there is nothing to show
                    shown["eval_sr"] = f"{self.last_eval:.2f}"
                self.bar.set_postfix(shown, refresh=False)
            return True

        def evaluate(self):
            sr, err, rew = periodic_evaluation(self.model, self.training_env, cfg, meta)
            self.last_eval = sr
            if (sr, -err) >= self.best:  # keep the best-evaluated policy, as rl-zoo does
                self.best = (sr, -err)
                artifacts.save(run / BEST_DIR, self.model, {**meta, "timesteps": self.num_timesteps,
                                                            "eval_success_rate": sr, "eval_mean_final_mm": err})
            self.evals.writerow([self.num_timesteps, sr, err, rew, time.time() - self.t0])
            self.logger.record("eval/success_rate", sr)
            self.logger.record("eval/mean_final_mm", err)
            self.logger.record("time/steps_per_s", (self.num_timesteps - self.s0) / (time.time() - self.t0))

        def _on_training_end(self) -> None:
            self.checkpoint_if_due()
            self.bar.close()

        def close_logs(self) -> None:
            self.episodes.close()
            self.evals.close()

    return Training()


def set_actor_trainable(policy, trainable: bool) -> None:
    """Freeze or release every parameter but the value function's (TrainConfig.critic_warmup_steps): frozen ones
    get no gradient, so PPO's update moves the value function alone and Adam leaves the actor as it is."""
    for name, param in policy.named_parameters():
        if not name.startswith(artifacts.VALUE_PARAMS):
            param.requires_grad_(trainable)


def guide_limit(cfg: TrainConfig, timesteps: int) -> int:
    """The most demonstrator steps an episode may begin with at this point of training (TrainConfig.guide_steps)."""
    decay = cfg.guide_decay_steps or cfg.total_timesteps
    return int(round(cfg.guide_steps * max(0.0, 1.0 - timesteps / decay)))


def checkpoints(run: Path) -> list[tuple[int, Path]]:
    """(steps, path) of the run's checkpoints, oldest first; other files in the folder are ignored."""
    found = [(int(m.group(1)), p) for p in (run / CKPT_DIR).glob("model_*.zip") if (m := CKPT_RE.fullmatch(p.name))]
    return sorted(found)


def latest_checkpoint(run: Path) -> Path | None:
    found = checkpoints(run)
    return found[-1][1] if found else None


def save_checkpoint(model, run: Path, sampler: TargetSampler | None = None) -> Path:
    """Model + normalisation stats (+ the target sampler's solve rates), written atomically; keeps the last two."""
    d = run / CKPT_DIR
    d.mkdir(parents=True, exist_ok=True)
    path = d / f"model_{model.num_timesteps}.zip"
    tmp = d / "partial.zip"
    model.save(str(tmp))
    env = model.get_env()
    if hasattr(env, "obs_rms"):
        env.save(str(d / f"vecnormalize_{model.num_timesteps}.pkl"))
    if sampler is not None:
        sampler.save(d / f"sampling_{model.num_timesteps}.json")
    os.replace(tmp, path)
    for steps, old in checkpoints(run)[:-2]:
        old.unlink()
        (d / f"vecnormalize_{steps}.pkl").unlink(missing_ok=True)
        (d / f"sampling_{steps}.json").unlink(missing_ok=True)
    return path


def _best_so_far(run: Path) -> tuple[float, float]:
    m = artifacts.read_meta(run / BEST_DIR) if (run / BEST_DIR).exists() else {}
    if "eval_success_rate" not in m:
        return (-1.0, -float("inf"))
    return (m["eval_success_rate"], -m["eval_mean_final_mm"])


def _writable(path: Path) -> None:
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / ".write_test"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        raise ConfigError(f"cannot write the run folder {path}: {exc.strerror}; pass --out to a writable "
                          "folder") from exc


def learning_rate_schedule(cfg: TrainConfig):
    """The config's rate as SB3 wants it: constant, or linear from learning_rate down to 0 at the budget's end."""
    lr0 = float(cfg.ppo.learning_rate)
    if cfg.ppo.lr_schedule == "linear":
        return lambda remaining: lr0 * remaining
    return lambda _remaining: lr0


def torch_device(cfg: TrainConfig) -> str:
    """PPO's device: the GPU when the physics runs there (batched backend), else the CPU (small MLP, 2 envs)."""
    import torch

    return "cuda" if cfg.backend == "warp" and torch.cuda.is_available() else "cpu"


def build_ppo(cfg: TrainConfig, venv, tensorboard_log: str | None = None):
    """A fresh PPO from a resolved config: the one place the config's PPO fields become SB3 arguments."""
    import torch
    from stable_baselines3 import PPO

    p = cfg.ppo
    policy, kwargs = "MlpPolicy", {}
    if cfg.critic_only:
        from mjendo.asymmetric import AsymmetricPolicy, actor_inputs

        policy, kwargs = AsymmetricPolicy, {"actor_inputs": actor_inputs(cfg.task_config(), cfg.critic_only)}
    model = PPO(policy, venv, seed=cfg.seed, device=torch_device(cfg), verbose=0, tensorboard_log=tensorboard_log,
                learning_rate=learning_rate_schedule(cfg), n_steps=p.n_steps, batch_size=p.batch_size,
                n_epochs=p.n_epochs, gamma=p.gamma, gae_lambda=p.gae_lambda, clip_range=p.clip_range,
                ent_coef=p.ent_coef,
                policy_kwargs={"net_arch": {"pi": list(p.net_arch), "vf": list(p.net_arch)},
                               "activation_fn": torch.nn.Tanh, "log_std_init": p.log_std_init, **kwargs})
    return with_weight_decay(model, p.weight_decay)


def with_weight_decay(model, weight_decay: float):
    """``model`` whose optimizer applies this run's L2 penalty (a loaded one keeps the source run's otherwise)."""
    for group in model.policy.optimizer.param_groups:
        group["weight_decay"] = weight_decay
    return model


def _start_from(cfg: TrainConfig, venv):
    """A PPO initialised from a trained policy folder, with a fresh learning-rate schedule (fine-tuning)."""
    from stable_baselines3 import PPO

    src = model_home(paths.data_path(cfg.init_from))
    if not (src / MODEL_FILE).exists():
        raise ConfigError(f"init_from {src} holds no {MODEL_FILE}; give a policy folder such as "
                          "models/policies/E or a finished run folder")
    if artifacts.is_actor_only(src / MODEL_FILE):
        raise ConfigError(f"init_from {src} is a study seed's evaluation copy (its value function is not stored): "
                          "start from a shipped policy folder, or train that seed again")
    have, want = artifacts.obs_options(src), obs_options(cfg.task_config())
    for key, what in (("residual", "corrects the baseline controller's actions"),
                      ("task_space", "asks the controller for a tip displacement")):
        if have[key] != want[key]:
            how = f"{what} ({key}) and this run does not" if have[key] else f"does not and this run {what} ({key})"
            raise ConfigError(f"init_from {src} {how}: an action means something else in each; train from "
                              f"scratch or from a policy with the same {key} setting")
    if have != want:
        # New blocks must come after all of the source's (widening appends inputs): none dropped, none in between.
        added = [k for k in OBS_OPTIONS if want[k] and not have[k]]
        last = max((OBS_OPTIONS.index(k) for k in OBS_OPTIONS if have[k]), default=-1)
        if any(have[k] and not want[k] for k in OBS_OPTIONS) or OBS_OPTIONS.index(added[0]) < last:
            raise ConfigError(f"init_from {src} observes {have}, this run {want}: a fine-tune can only add the "
                              "contact force (force_obs), the scope's state (scope_obs), the time left (time_obs), "
                              "the breathing phase (phase_obs), the last step (step_obs), the wall's depth "
                              "(depth_obs), the target's surface normal (normal_obs), the map's plan (plan_obs) or "
                              "the last observations (history_obs) after the source's inputs, not drop or reorder them")
        return _widened_start(cfg, venv, src)
    if _hidden_layers(PPO.load(str(src / MODEL_FILE), device="cpu")) != list(cfg.ppo.net_arch):
        return _widened_start(cfg, venv, src)
    venv = _source_normalizer(cfg, venv, src)
    schedule = learning_rate_schedule(cfg)
    p = cfg.ppo  # this run's PPO settings and seed rule, not the ones the policy was trained with (with the
    # source's seed every fine-tune of one policy would draw the same actions and episodes)
    model = PPO.load(str(src / MODEL_FILE), env=venv, device=torch_device(cfg),
                     custom_objects={"learning_rate": schedule, "lr_schedule": schedule}, seed=cfg.seed,
                     n_steps=p.n_steps, batch_size=p.batch_size, n_epochs=p.n_epochs, gamma=p.gamma,
                     gae_lambda=p.gae_lambda, clip_range=p.clip_range, ent_coef=p.ent_coef)
    with_weight_decay(model, p.weight_decay)
    model.num_timesteps = 0  # this run's budget counts from here
    if cfg.critic_only and getattr(model.policy, "actor_inputs", None) is None:
        raise ConfigError(f"init_from {src} already acts on {cfg.critic_only}: they cannot become critic-only "
                          "inputs; start from a policy that does not observe them (it is widened) or from scratch")
    return model


def _hidden_layers(model) -> list[int]:
    """A PPO's hidden layers (its actor's; build_ppo gives the critic the same)."""
    net = model.policy_kwargs.get("net_arch", [])
    return list(net["pi"] if isinstance(net, dict) else net)


def _source_normalizer(cfg: TrainConfig, venv, src: Path):
    """``venv`` normalised by the source's statistics, which keep adapting to this run's stomach."""
    from stable_baselines3.common.vec_env import VecNormalize

    if not cfg.normalize:
        return venv
    venv = VecNormalize.load(str(src / NORM_FILE), venv)
    venv.training = True
    venv.gamma = cfg.ppo.gamma  # rewards scale by this run's discounted returns, not the source's
    return venv


def _widened_start(cfg: TrainConfig, venv, src: Path):
    """A PPO that also observes more (contact force, scope state, time left, phase) or has wider hidden layers,
    acting at first exactly as the policy in ``src``."""
    from stable_baselines3 import PPO

    from mjendo.widen import widen_state, widened_normalizer

    source = PPO.load(str(src / MODEL_FILE), device=torch_device(cfg))
    model = build_ppo(cfg, venv)
    n = source.observation_space.shape[0]
    model.policy.load_state_dict(widen_state(source.policy.state_dict(), model.policy.state_dict(), n,
                                             cfg.widen_scale, cfg.seed))
    if model.observation_space.shape[0] == n:  # only the hidden layers grow
        model.set_env(_source_normalizer(cfg, venv, src))
    elif cfg.normalize:
        model.set_env(widened_normalizer(src / NORM_FILE, venv, cfg.ppo.gamma, model))
    weight = f"at {cfg.widen_scale:g} x the old ones' spread" if cfg.widen_scale else "at zero weight"
    inputs = f"{n} inputs -> {model.observation_space.shape[0]} (the new ones {weight}), "
    print(f"widened {src}: {inputs if model.observation_space.shape[0] > n else ''}hidden layers "
          f"{_hidden_layers(source)} -> {list(cfg.ppo.net_arch)}")
    return model


def _run_config(run: Path, cfg: TrainConfig) -> TrainConfig:
    """On resume the run's own config rules (only the budget may grow); a new run records its config."""
    saved = run / "config.yaml"
    if saved.exists():
        try:
            own = from_dict(TrainConfig, yaml.safe_load(saved.read_text()), str(saved))
        except (ConfigError, yaml.YAMLError, TypeError) as exc:
            raise ConfigError(f"{saved} is not a valid run config ({exc}); pass --fresh to start the run again") \
                from exc
        own.total_timesteps = cfg.total_timesteps
        own.check()
        return own
    return cfg


def run_folder(cfg: TrainConfig, out: Path, run_name: str | None) -> Path:
    default = (f"{cfg.variant}-" if cfg.variant else "") + f"seed{cfg.seed}" \
        + ("" if cfg.fidelity == "fast" else f"-{cfg.fidelity}")
    return Path(out) / cfg.policy / (run_name or default)


def train(policy: str, timesteps: int | None = None, seed: int | None = None, n_envs: int | None = None,
          out: Path | None = None, run_name: str | None = None, fresh: bool = False,
          vec_env: str | None = None, ship: bool = False, config_file: Path | None = None,
          fidelity: str | None = None, init_from: Path | None = None, learning_rate: float | None = None,
          progress: bool = True, backend: str | None = None, variant: str | None = None) -> Path:
    """Train (or resume) one policy; returns the run folder (``progress=False``: no progress bar)."""
    cfg = load_config(policy, config_file or paths.TRAINING_CONFIG, variant, total_timesteps=timesteps, seed=seed,
                      n_envs=n_envs, vec_env=vec_env, fidelity=fidelity, init_from=init_from,
                      learning_rate=learning_rate, backend=backend)
    run = run_folder(cfg, out or paths.RUNS, run_name)
    _writable(run)
    if fresh and run.exists():
        shutil.rmtree(run)
        _writable(run)
    cfg = _run_config(run, cfg)
    print(f"run folder: {run}", flush=True)

    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecNormalize

    torch.set_num_threads(1)
    # torch checks every distribution's arguments when SB3 builds one (each rollout step, each minibatch):
    # 2-3 % of a training step here, and the policy's outputs are finite by construction.
    torch.distributions.Distribution.set_default_validate_args(False)
    meta = {"policy": policy, "seed": cfg.seed, "init_from": cfg.init_from, **artifacts.task_meta(cfg.task_config())}
    if cfg.backend == "warp":
        from mjendo.batch import vec_env

        venv = vec_env(cfg.n_envs, cfg.task_config(), seed=cfg.seed)
    else:
        Vec = SubprocVecEnv if cfg.vec_env == "subproc" and cfg.n_envs > 1 else DummyVecEnv
        venv = Vec([make_env(cfg, i) for i in range(cfg.n_envs)])
    ckpt = latest_checkpoint(run)
    if ckpt is not None:
        steps = int(CKPT_RE.fullmatch(ckpt.name).group(1))
        norm = ckpt.parent / f"vecnormalize_{steps}.pkl"
        try:
            if cfg.normalize:
                venv = VecNormalize.load(str(norm), venv)
            model = PPO.load(str(ckpt), env=venv, device=torch_device(cfg))
        except Exception as exc:
            venv.close()
            files = f"{ckpt} (with {norm.name})" if cfg.normalize else str(ckpt)
            raise ConfigError(f"checkpoint {files} is unreadable ({exc}); delete it to fall back to the "
                              "previous one, or pass --fresh") from exc
        print(f"resuming from {ckpt.name} ({steps} steps)")
    else:
        if cfg.init_from:
            model = _start_from(cfg, venv)
            model.tensorboard_log = str(run / "tb")
            print(f"fine-tuning {cfg.init_from} in the {cfg.fidelity} stomach")
        else:
            if cfg.normalize:
                venv = VecNormalize(venv, gamma=cfg.ppo.gamma)
            model = build_ppo(cfg, venv, tensorboard_log=str(run / "tb"))
        (run / "config.yaml").write_text(yaml.safe_dump(cfg.to_dict(), sort_keys=False))

    if cfg.freeze_normalization and hasattr(model.get_env(), "obs_rms"):
        model.get_env().training = False  # the statistics the run started with, on resume too
    start, total = model.num_timesteps, cfg.total_timesteps
    final_meta = artifacts.read_meta(run)
    if start >= total and (run / MODEL_FILE).exists() and final_meta.get("timesteps"):
        venv.close()
        print(f"{run} is complete ({start} steps)")
        _finish(run, policy, ship)
        return run
    cb = _callbacks(cfg, run, meta, start, progress)
    # SIGTERM (e.g. a scheduler) stops like Ctrl-C: checkpoint, then exit.
    signal.signal(signal.SIGTERM, lambda *_: (_ for _ in ()).throw(KeyboardInterrupt()))
    t0 = time.time()
    try:
        if total > start:
            model.learn(total - start, callback=cb, reset_num_timesteps=False, tb_log_name="ppo")
    except KeyboardInterrupt:
        path = save_checkpoint(model, run, cb.sampler)
        print(f"\ninterrupted: saved {path}; run the same command to resume")
        venv.close()
        raise SystemExit(130) from None
    finally:
        cb.close_logs()
    wall = time.time() - t0
    meta.update({"timesteps": int(model.num_timesteps), "wall_s": final_meta.get("wall_s", 0.0) + wall,
                 "steps_per_s": (model.num_timesteps - start) / max(wall, 1e-9), "command": command_as_typed(),
                 "training": cfg.to_dict()})
    artifacts.save(run, model, meta)
    venv.close()
    from mjendo.figures import training_curve

    training_curve(run, run / "curve.png")
    print(f"done: {run} ({meta['timesteps']} steps, {meta['wall_s'] / 60:.1f} min)")
    _finish(run, policy, ship)
    return run


def command_as_typed() -> str:
    """The training command as a user types it (not a worker's interpreter path)."""
    return shlex.join(["python", "-m", "mjendo.train", *sys.argv[1:]])


def _finish(run: Path, policy: str, ship: bool) -> None:
    """Ship if asked, and say how to use the result."""
    if ship:
        print(f"shipped to {artifacts.ship(run, policy)}")
    make = f" (= make ship POLICY={policy} RUN={run.name})" if run.parent.parent.resolve() == paths.RUNS else ""
    print(f"watch it:    python -m mjendo.viewer --headless --record {policy}.mp4 --policy {run}\n"
          f"evaluate it: python -m mjendo.evaluation --policies {run} --trials 100\n"
          f"ship it:     python -m mjendo.artifacts ship {run} {policy}{make}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m mjendo.train", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--policy", required=True, help="A, B, C, D or E")
    ap.add_argument("--timesteps", type=int)
    ap.add_argument("--seed", type=int)
    ap.add_argument("--n-envs", type=int)
    ap.add_argument("--vec-env", choices=["subproc", "dummy"])
    ap.add_argument("--out", type=Path, default=paths.RUNS)
    ap.add_argument("--run", help="run name (default seed<N>, or <variant>-seed<N>)")
    ap.add_argument("--variant", help="an entry of the config's variants block (e.g. scope-curriculum for E)")
    ap.add_argument("--fresh", action="store_true", help="discard an existing run instead of resuming")
    ap.add_argument("--ship", action="store_true", help="copy the finished policy to models/policies/")
    ap.add_argument("--config", type=Path, help="training config (default train/policies.yaml)")
    ap.add_argument("--fidelity", choices=list(FIDELITIES), help="stomach to train in (default: the config's)")
    ap.add_argument("--init-from", type=Path, metavar="POLICY_DIR",
                    help="fine-tune a trained policy (e.g. models/policies/E) with the config's finetune block")
    ap.add_argument("--learning-rate", type=float)
    ap.add_argument("--backend", choices=["cpu", "warp"],
                    help="warp: every environment a world of MuJoCo Warp on the GPU (the config's batched block)")
    a = ap.parse_args(argv)
    return cli.run(lambda: train(a.policy, a.timesteps, a.seed, a.n_envs, a.out, a.run, a.fresh, a.vec_env, a.ship,
                                 a.config, a.fidelity, a.init_from, a.learning_rate, backend=a.backend,
                                 variant=a.variant),
                   ConfigError, PolicyError)


if __name__ == "__main__":
    raise SystemExit(main())
