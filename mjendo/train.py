"""Train the paper's policies with PPO: ``python -m mjendo.train --policy E`` (or ``make train POLICY=E``).

A run lives in ``runs/<policy>/<run>/``: the resolved config, episodes.csv
(every training episode), evaluations.csv (periodic 80-step evaluation:
success rate, mean final error), TensorBoard logs, checkpoints and, at the
end, model.zip + vecnormalize.pkl + curve.png. Running the same command
again resumes from the last checkpoint; ``--ship`` copies the final policy
to ``models/policies/<policy>/``.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shutil
import signal
import sys
import time
from pathlib import Path

import numpy as np
import yaml

from mjendo.config import PAPER_EVAL_STEPS, ConfigError
from mjendo.policies import MODEL_FILE, NORM_FILE, POLICIES_DIR, POLICY_NAMES

ROOT = Path(__file__).resolve().parent.parent
CONFIG_FILE = ROOT / "train" / "policies.yaml"
CKPT_DIR = "checkpoints"
BEST_DIR = "best"


def load_config(policy: str, path: Path | None = None, **overrides) -> dict:
    """The resolved training config of one policy (defaults + entry + overrides)."""
    if policy not in POLICY_NAMES:
        raise ConfigError(f"unknown policy {policy!r}; valid: {', '.join(POLICY_NAMES)}")
    path = Path(path or CONFIG_FILE)
    if not path.exists():
        raise ConfigError(f"training config {path} does not exist")
    raw = yaml.safe_load(path.read_text())
    cfg = {**raw["defaults"], **raw["policies"][policy], "policy": policy}
    cfg["ppo"] = dict(raw["defaults"]["ppo"])
    finetune = cfg.pop("finetune", {})
    if overrides.get("init_from") is not None:
        # Fine-tuning (e.g. in the full FEM stomach): the config's finetune block, then the CLI's values.
        cfg["ppo"]["learning_rate"] = finetune.get("learning_rate", cfg["ppo"]["learning_rate"])
        cfg = {**cfg, **{k: v for k, v in finetune.items() if k != "learning_rate"}}
        cfg["init_from"] = str(overrides["init_from"])
    for k, v in overrides.items():
        if v is not None and k not in ("init_from", "learning_rate"):
            cfg[k] = v
    if overrides.get("learning_rate") is not None:
        cfg["ppo"]["learning_rate"] = float(overrides["learning_rate"])
    if cfg["vec_env"] not in ("subproc", "dummy"):
        raise ConfigError(f"vec_env must be 'subproc' or 'dummy', not {cfg['vec_env']!r}")
    return cfg


def make_env(cfg: dict, rank: int, max_steps: int | None = None):
    def thunk():
        import torch
        from stable_baselines3.common.monitor import Monitor

        import mjendo  # noqa: F401
        from mjendo.envs import EndoscopeEnv

        torch.set_num_threads(1)
        kw = {"max_steps": max_steps} if max_steps else {}
        env = Monitor(EndoscopeEnv(cfg["env"], force_obs=cfg["force_obs"], fidelity=cfg["fidelity"], **kw),
                      info_keywords=("is_success", "distance_mm"))
        env.reset(seed=cfg["seed"] * 1000 + rank)
        return env

    return thunk


def _callbacks(cfg: dict, run: Path, eval_env, start_steps: int, total: int):
    from stable_baselines3.common.callbacks import BaseCallback
    from tqdm import tqdm

    class Training(BaseCallback):
        """Episode log, periodic evaluation, checkpoints and a progress bar."""

        def __init__(self):
            super().__init__()
            self.episodes = _csv(run / "episodes.csv", ["timesteps", "reward", "length", "success", "final_mm"])
            self.evals = _csv(run / "evaluations.csv", ["timesteps", "success_rate", "mean_final_mm",
                                                        "mean_reward", "wall_s"])
            self.next_eval = (start_steps // cfg["eval_every"] + 1) * cfg["eval_every"]
            self.next_ckpt = (start_steps // cfg["checkpoint_every"] + 1) * cfg["checkpoint_every"]
            self.bar = tqdm(total=total, initial=start_steps, unit="step", desc=f"policy {cfg['policy']}",
                            dynamic_ncols=True, mininterval=2.0, file=sys.stdout)
            self.t0, self.s0 = time.time(), start_steps
            self.recent: list[float] = []
            self.last_eval = float("nan")
            self.best = _best_so_far(run)

        def _on_step(self) -> bool:
            for info in self.locals["infos"]:
                ep = info.get("episode")
                if ep is not None:
                    self.episodes.writerow([self.num_timesteps, ep["r"], ep["l"], int(info["is_success"]),
                                            info["distance_mm"]])
                    self.recent = (self.recent + [float(info["is_success"])])[-100:]
            n = self.model.n_envs
            self.bar.update(n)
            if self.num_timesteps >= self.next_eval:
                self.next_eval += cfg["eval_every"]
                self.evaluate()
            if self.num_timesteps >= self.next_ckpt:
                self.next_ckpt += cfg["checkpoint_every"]
                save_checkpoint(self.model, run)
            if self.n_calls % 50 == 0:
                rate = (self.num_timesteps - self.s0) / max(time.time() - self.t0, 1e-9)
                self.bar.set_postfix(steps_s=f"{rate:.0f}", success=f"{np.mean(self.recent or [0]):.2f}",
                                     eval_sr=f"{self.last_eval:.2f}", refresh=False)
            return True

        def evaluate(self):
            sr, err, rew = evaluate_policy(self.model, eval_env, cfg["eval_episodes"], self.training_env)
            self.last_eval = sr
            if (sr, -err) >= self.best:  # keep the best-evaluated policy, as rl-zoo does
                self.best = (sr, -err)
                save_policy(self.model, run / BEST_DIR, {"timesteps": self.num_timesteps, "eval_success_rate": sr,
                                                         "eval_mean_final_mm": err})
            self.evals.writerow([self.num_timesteps, sr, err, rew, time.time() - self.t0])
            self.logger.record("eval/success_rate", sr)
            self.logger.record("eval/mean_final_mm", err)
            self.logger.record("time/steps_per_s", (self.num_timesteps - self.s0) / (time.time() - self.t0))

        def _on_training_end(self) -> None:
            self.bar.close()

    return Training()


class _Appender:
    def __init__(self, path: Path, header: list[str]):
        new = not path.exists()
        self.f = open(path, "a", newline="")  # noqa: SIM115 (kept open for the run)
        self.w = csv.writer(self.f)
        if new:
            self.w.writerow(header)

    def writerow(self, row) -> None:
        self.w.writerow(row)
        self.f.flush()


def _csv(path: Path, header: list[str]) -> _Appender:
    return _Appender(path, header)


def evaluate_policy(model, eval_env, episodes: int, train_env=None) -> tuple[float, float, float]:
    """Deterministic 80-step trials: success rate, mean final error (mm), mean reward."""
    if train_env is not None and hasattr(train_env, "obs_rms"):
        eval_env.obs_rms = train_env.obs_rms
    succ, err, rew = [], [], []
    for _ in range(episodes):
        obs = eval_env.reset()
        total, done = 0.0, False
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, r, dones, infos = eval_env.step(action)
            total += float(eval_env.get_original_reward()[0]) if hasattr(eval_env, "get_original_reward") \
                else float(r[0])
            done = bool(dones[0])
        succ.append(float(infos[0]["is_success"]))
        err.append(float(infos[0]["distance_mm"]))
        rew.append(total)
    return float(np.mean(succ)), float(np.mean(err)), float(np.mean(rew))


def latest_checkpoint(run: Path) -> Path | None:
    ckpts = sorted((run / CKPT_DIR).glob("model_*.zip"), key=lambda p: int(p.stem.split("_")[1]))
    return ckpts[-1] if ckpts else None


def save_checkpoint(model, run: Path) -> Path:
    """Model + normalisation stats, written atomically; keeps the last two."""
    d = run / CKPT_DIR
    d.mkdir(parents=True, exist_ok=True)
    path = d / f"model_{model.num_timesteps}.zip"
    tmp = d / "partial.zip"
    model.save(str(tmp))
    env = model.get_env()
    if hasattr(env, "save"):
        env.save(str(d / f"vecnormalize_{model.num_timesteps}.pkl"))
    os.replace(tmp, path)
    for old in sorted(d.glob("model_*.zip"), key=lambda p: int(p.stem.split("_")[1]))[:-2]:
        old.unlink()
        (d / f"vecnormalize_{old.stem.split('_')[1]}.pkl").unlink(missing_ok=True)
    return path


def save_policy(model, directory: Path, meta: dict) -> None:
    """model.zip + vecnormalize.pkl + meta.json in ``directory``."""
    directory.mkdir(parents=True, exist_ok=True)
    model.save(str(directory / MODEL_FILE))
    env = model.get_env()
    if hasattr(env, "save"):
        env.save(str(directory / NORM_FILE))
    (directory / "meta.json").write_text(json.dumps(meta, indent=1) + "\n")


def _best_so_far(run: Path) -> tuple[float, float]:
    meta = run / BEST_DIR / "meta.json"
    if not meta.exists():
        return (-1.0, -float("inf"))
    m = json.loads(meta.read_text())
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


def learning_rate_schedule(cfg: dict):
    """The config's rate as SB3 wants it: constant, or linear from learning_rate down to 0 at the budget's end."""
    lr0 = float(cfg["ppo"]["learning_rate"])
    if cfg["ppo"].get("lr_schedule", "constant") == "linear":
        return lambda remaining: lr0 * remaining
    return lambda _remaining: lr0


def build_ppo(cfg: dict, venv, tensorboard_log: str | None = None):
    """A fresh PPO from a resolved config: the one place the config's PPO fields become SB3 arguments."""
    import torch
    from stable_baselines3 import PPO

    ppo = dict(cfg["ppo"])
    arch = ppo.pop("net_arch")
    log_std = ppo.pop("log_std_init")
    ppo.pop("lr_schedule", None)
    ppo["learning_rate"] = learning_rate_schedule(cfg)
    return PPO("MlpPolicy", venv, seed=cfg["seed"], device="cpu", verbose=0, tensorboard_log=tensorboard_log,
               policy_kwargs={"net_arch": {"pi": arch, "vf": arch}, "activation_fn": torch.nn.Tanh,
                              "log_std_init": log_std},
               **ppo)


def _start_from(cfg: dict, venv):
    """A PPO initialised from a trained policy folder, with a fresh learning-rate schedule (fine-tuning)."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    src = Path(cfg["init_from"])
    if not (src / MODEL_FILE).exists():
        raise ConfigError(f"--init-from {src} holds no {MODEL_FILE}; give a policy folder such as "
                          "models/policies/E or a finished run folder")
    if cfg["normalize"]:
        venv = VecNormalize.load(str(src / NORM_FILE), venv)  # keeps adapting to the new stomach
        venv.training = True
    schedule = learning_rate_schedule(cfg)
    model = PPO.load(str(src / MODEL_FILE), env=venv, device="cpu",
                     custom_objects={"learning_rate": schedule, "lr_schedule": schedule})
    model.num_timesteps = 0  # this run's budget counts from here
    return model


def train(policy: str, timesteps: int | None = None, seed: int | None = None, n_envs: int | None = None,
          out: Path = ROOT / "runs", run_name: str | None = None, fresh: bool = False,
          vec_env: str | None = None, ship: bool = False, config_file: Path | None = None,
          fidelity: str | None = None, init_from: Path | None = None, learning_rate: float | None = None) -> Path:
    """Train (or resume) one policy; returns the run folder."""
    cfg = load_config(policy, config_file, total_timesteps=timesteps, seed=seed, n_envs=n_envs, vec_env=vec_env,
                      fidelity=fidelity, init_from=init_from, learning_rate=learning_rate)
    default_name = f"seed{cfg['seed']}" + ("" if cfg["fidelity"] == "fast" else f"-{cfg['fidelity']}")
    run = Path(out) / policy / (run_name or default_name)
    _writable(run)
    if fresh and run.exists():
        shutil.rmtree(run)
        _writable(run)

    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecNormalize

    torch.set_num_threads(1)
    Vec = SubprocVecEnv if cfg["vec_env"] == "subproc" and cfg["n_envs"] > 1 else DummyVecEnv
    venv = Vec([make_env(cfg, i) for i in range(cfg["n_envs"])])
    eval_env = DummyVecEnv([make_env({**cfg, "seed": cfg["seed"] + 7919}, 0, max_steps=PAPER_EVAL_STEPS)])
    ckpt = latest_checkpoint(run)
    if ckpt is not None:
        steps = int(ckpt.stem.split("_")[1])
        norm = ckpt.parent / f"vecnormalize_{steps}.pkl"
        try:
            if cfg["normalize"]:
                venv = VecNormalize.load(str(norm), venv)
            model = PPO.load(str(ckpt), env=venv, device="cpu")
        except Exception as exc:
            venv.close()
            files = f"{ckpt} (with {norm.name})" if cfg["normalize"] else str(ckpt)
            raise ConfigError(f"checkpoint {files} is unreadable ({exc}); delete it to fall back to the "
                              "previous one, or pass --fresh") from exc
        print(f"resuming {run} from {ckpt.name} ({steps} steps)")
    else:
        if cfg.get("init_from"):
            model = _start_from(cfg, venv)
            model.tensorboard_log = str(run / "tb")
            print(f"fine-tuning {cfg['init_from']} in the {cfg['fidelity']} stomach")
        else:
            if cfg["normalize"]:
                venv = VecNormalize(venv, gamma=cfg["ppo"]["gamma"])
            model = build_ppo(cfg, venv, tensorboard_log=str(run / "tb"))
        (run / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
    if cfg["normalize"]:
        eval_env = VecNormalize(eval_env, training=False, norm_reward=False, gamma=cfg["ppo"]["gamma"])

    start = model.num_timesteps
    total = int(cfg["total_timesteps"])
    if start >= total and (run / MODEL_FILE).exists():
        venv.close()
        print(f"{run} is complete ({start} steps)")
        if ship:
            print(f"shipped to {ship_policy(run, policy)}")
        return run
    cb = _callbacks(cfg, run, eval_env, start, total)
    # SIGTERM (e.g. a scheduler) stops like Ctrl-C: checkpoint, then exit.
    signal.signal(signal.SIGTERM, lambda *_: (_ for _ in ()).throw(KeyboardInterrupt()))
    t0 = time.time()
    try:
        if total > start:
            model.learn(total - start, callback=cb, reset_num_timesteps=False, tb_log_name="ppo")
    except KeyboardInterrupt:
        path = save_checkpoint(model, run)
        print(f"\ninterrupted: saved {path}; run the same command to resume")
        venv.close()
        raise SystemExit(130) from None
    wall = time.time() - t0
    model.save(str(run / MODEL_FILE))
    if cfg["normalize"]:
        model.get_env().save(str(run / NORM_FILE))
    prev = json.loads((run / "meta.json").read_text()) if (run / "meta.json").exists() else {}
    meta = {"policy": policy, "env": cfg["env"], "fidelity": cfg["fidelity"], "force_obs": cfg["force_obs"],
            "seed": cfg["seed"], "init_from": cfg.get("init_from"),
            "timesteps": int(model.num_timesteps), "wall_s": prev.get("wall_s", 0.0) + wall,
            "steps_per_s": (model.num_timesteps - start) / max(wall, 1e-9), "config": cfg,
            "action_scales": _action_scales(cfg), "command": " ".join(sys.argv)}
    (run / "meta.json").write_text(json.dumps(meta, indent=1) + "\n")
    venv.close()
    from mjendo.figures import training_curve

    training_curve(run, run / "curve.png")
    if ship:
        ship_policy(run, policy)
    print(f"done: {run} ({meta['timesteps']} steps, {meta['wall_s'] / 60:.1f} min)")
    return run


def _action_scales(cfg: dict) -> dict[str, float]:
    """What the run's actions meant (mjendo's current task defaults); recorded so a loader can check."""
    from mjendo.config import task_config
    from mjendo.task import action_scales

    return action_scales(task_config(env=cfg["env"], fidelity=cfg["fidelity"]))


def ship_policy(run: Path, policy: str) -> Path:
    """Copy a finished run's final weights into models/policies/<policy>/ (what users get).

    Final, not ``best/``: with the learning rate decayed to 0 the end of the run
    is the converged policy, and picking the maximum of noisy 40-trial
    evaluations chose a worse one for E (docs/training.md).
    """
    dest = POLICIES_DIR / policy
    dest.mkdir(parents=True, exist_ok=True)
    for name in ("meta.json", "curve.png", "config.yaml", "evaluations.csv", "episodes.csv", MODEL_FILE, NORM_FILE):
        if (run / name).exists():
            shutil.copy2(run / name, dest / name)
    meta = json.loads((dest / "meta.json").read_text())
    meta.setdefault("action_scales", _action_scales(meta["config"]))
    (dest / "meta.json").write_text(json.dumps(meta, indent=1) + "\n")
    return dest


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m mjendo.train", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--policy", required=True, help="A, B, C, D or E")
    ap.add_argument("--timesteps", type=int)
    ap.add_argument("--seed", type=int)
    ap.add_argument("--n-envs", type=int)
    ap.add_argument("--vec-env", choices=["subproc", "dummy"])
    ap.add_argument("--out", type=Path, default=ROOT / "runs")
    ap.add_argument("--run", help="run name (default seed<N>)")
    ap.add_argument("--fresh", action="store_true", help="discard an existing run instead of resuming")
    ap.add_argument("--ship", action="store_true", help="copy the final policy to models/policies/")
    ap.add_argument("--config", type=Path, help=f"training config (default {CONFIG_FILE.relative_to(ROOT)})")
    ap.add_argument("--fidelity", choices=["fast", "full"], help="stomach to train in (default: the config's)")
    ap.add_argument("--init-from", type=Path, metavar="POLICY_DIR",
                    help="fine-tune a trained policy (e.g. models/policies/E) with the config's finetune block")
    ap.add_argument("--learning-rate", type=float)
    a = ap.parse_args(argv)
    try:
        train(a.policy, a.timesteps, a.seed, a.n_envs, a.out, a.run, a.fresh, a.vec_env, a.ship, a.config,
              a.fidelity, a.init_from, a.learning_rate)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
