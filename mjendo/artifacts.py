"""The policy folder: what a trained policy is on disk, written and read only here.

A policy folder (a finished run ``runs/<P>/seed<N>/``, its ``best/``, or a
shipped ``models/policies/<P>/``) holds:

| file | what |
|---|---|
| ``model.zip`` | the Stable-Baselines3 PPO model |
| ``vecnormalize.pkl`` | observation normalisation (VecNormalize), when the run normalised |
| ``meta.json`` | the task config it trained in, the observation layout, run facts (seed, steps, time) |
| ``config.yaml`` | the resolved training config of the run |
| ``episodes.csv``, ``evaluations.csv``, ``curve.png`` | training logs and curve |

Loading reads everything it needs from the folder itself (never from
today's training YAML) and checks that the pieces fit together. Both
``model.zip`` and ``vecnormalize.pkl`` are pickles: loading them runs
code, so load only policy folders you trust.
"""

from __future__ import annotations

import json
import os
import pickle
import shutil
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from mjendo import paths
from mjendo.config import POLICY_NAMES, ConfigError, TaskConfig, task_config

MODEL_FILE = "model.zip"
NORM_FILE = "vecnormalize.pkl"
META_FILE = "meta.json"
CONFIG_FILE = "config.yaml"
LOG_FILES = ("episodes.csv", "evaluations.csv", "curve.png")
SAME_RUN = ("seed", "timesteps", "wall_s", "commit")  # meta fields that tell one finished run from another
SEEDS_DIR = "seeds"  # models/policies/<P>/seeds/seed<N>/: every published training seed of a shipped policy
FORMAT = 2  # meta.json layout: 2 = with "task" and "observation"


class PolicyError(ValueError):
    """A policy cannot be loaded or does not fit the task; the message names the file and what to do."""


def observation_layout(cfg: TaskConfig) -> list[dict]:
    """(name, size, unit) of each observation block, in order: what a policy's input means."""
    from mjendo.task import obs_blocks, obs_options

    return [{"name": n, "size": k, "unit": u} for n, k, u, _ in obs_blocks(**obs_options(cfg))]


def commit() -> str | None:
    """The checkout's git commit (with "+dirty" when files differ from it), or None outside a checkout."""
    import subprocess

    if not paths.IN_CHECKOUT:
        return None
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=paths.DATA, capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=paths.DATA,
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None
    return head + ("+dirty" if dirty else "")


def task_meta(cfg: TaskConfig) -> dict:
    """The part of meta.json that says what task the policy acts in, and with which code and scenes."""
    import mjendo
    from mjendo import targets
    from mjendo.scene import fingerprint

    return {"format": FORMAT, "task": asdict(cfg), "observation": observation_layout(cfg),
            "mjendo_version": mjendo.__version__, "scene_fingerprint": fingerprint(cfg.fidelity, cfg.version),
            "targets_fingerprint": targets.fingerprint(cfg.version), "commit": commit()}


def write_meta(directory: Path, meta: dict) -> None:
    path = Path(directory) / META_FILE
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(meta, indent=1) + "\n")
    os.replace(tmp, path)


def save(directory: Path, model, meta: dict) -> None:
    """model.zip (+ vecnormalize.pkl when the model's env normalises) + meta.json."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    model.save(str(directory / MODEL_FILE))
    env = model.get_env()
    if hasattr(env, "obs_rms"):
        env.save(str(directory / NORM_FILE))
    write_meta(directory, meta)


def read_meta(directory: Path) -> dict:
    """meta.json as a dict, checked; a folder without one (a bare model.zip) gives {}."""
    path = Path(directory) / META_FILE
    if not path.exists():
        return {}
    try:
        meta = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise PolicyError(f"cannot read {path}: {exc}; restore it from the run folder or git") from exc
    if not isinstance(meta, dict):
        raise PolicyError(f"{path} must hold a JSON object (policy, task, observation, ...), not a "
                          f"{type(meta).__name__}; restore it from the run folder or git")
    if "task" in meta:
        if not isinstance(meta["task"], dict):
            raise PolicyError(f"{path}: 'task' must be an object of TaskConfig fields")
        try:
            task_config(**{k: v for k, v in meta["task"].items() if k in {f.name for f in fields(TaskConfig)}})
        except (ConfigError, TypeError) as exc:
            raise PolicyError(f"{path}: its task is not valid ({exc}); restore it from the run folder") from exc
    return meta


def trained_task(meta: dict) -> dict:
    """The TaskConfig fields the policy trained with (meta["task"]); a meta without a version is version 0."""
    return {"version": 0, **meta.get("task", {})}


@dataclass
class Policy:
    """A loaded policy: the PPO model, its observation normalisation and its meta."""

    directory: Path
    model: object  # stable_baselines3.PPO
    obs_rms: object | None  # RunningMeanStd
    clip_obs: float
    epsilon: float
    meta: dict

    @property
    def name(self) -> str:
        return str(self.meta.get("policy", self.directory.name))

    @property
    def n_obs(self) -> int:
        return int(self.model.observation_space.shape[0])


def _load_norm(path: Path, n_obs: int):
    from stable_baselines3.common.vec_env import VecNormalize

    try:
        with open(path, "rb") as f:
            vn = pickle.load(f)
    except Exception as exc:  # truncated file, unknown classes, not a pickle
        raise PolicyError(f"cannot read {path}: {exc}; it is corrupt: copy it again from the run folder "
                          "(checkpoints/vecnormalize_<steps>.pkl)") from exc
    if not isinstance(vn, VecNormalize):
        raise PolicyError(f"{path} holds a {type(vn).__name__}, not a Stable-Baselines3 VecNormalize; copy the "
                          "run's own vecnormalize.pkl next to its model.zip")
    shape = tuple(np.shape(getattr(vn.obs_rms, "mean", ())))
    if shape != (n_obs,):
        raise PolicyError(f"{path} normalises {shape[0] if shape else 0} observations but {path.parent / MODEL_FILE} "
                          f"takes {n_obs}: the two files come from different runs; copy the matching "
                          "vecnormalize.pkl from the model's run folder")
    return vn


def model_home(directory: Path) -> Path:
    """The folder holding a policy's model.zip and vecnormalize.pkl: the folder itself, or for the shipped
    seed's published folder (``<P>/seeds/seed<N>/``, kept without them) the shipped policy: one copy in git."""
    directory = Path(directory)
    shipped = directory.parent.parent
    if (directory / MODEL_FILE).exists() or directory.parent.name != SEEDS_DIR or not (shipped / MODEL_FILE).exists():
        return directory
    ours, theirs = read_meta(directory), read_meta(shipped)
    return shipped if all(ours.get(k) == theirs.get(k) for k in SAME_RUN) else directory


def load(directory: Path) -> Policy:
    """Load and check a policy folder; every problem is one PolicyError naming the file and the fix."""
    from stable_baselines3 import PPO

    directory = Path(directory)
    path = model_home(directory) / MODEL_FILE
    if not path.exists() and directory.parent.name == SEEDS_DIR and (directory / META_FILE).exists():
        meta = read_meta(directory)
        variant = meta.get("training", {}).get("variant")
        raise PolicyError(f"{directory} is a published seed kept without its weights (its study trials are the "
                          f"record): train it again with `python -m mjendo.train --policy {meta.get('policy')}"
                          + (f" --variant {variant}" if variant else "") + f" --seed {meta.get('seed')}`, or "
                          f"restore them from git history (`git log -- {directory}/{MODEL_FILE}`)")
    if not path.exists():
        raise PolicyError(f"no policy file at {path}: train one with `make train POLICY=...`, pass a folder "
                          "holding model.zip, or use task version 0's shipped ones (models/policies/v0/<P>)")
    meta = read_meta(directory)
    try:
        model = PPO.load(str(path), device="cpu")
    except Exception as exc:  # zip/pickle/torch errors
        raise PolicyError(f"cannot load {path}: {exc}; the file is corrupt or not an SB3 PPO model") from exc
    n_obs = int(model.observation_space.shape[0])
    layout = meta.get("observation")
    if layout is not None and sum(int(b["size"]) for b in layout) != n_obs:
        raise PolicyError(f"{directory / META_FILE} describes {sum(int(b['size']) for b in layout)} observations but "
                          f"{path} takes {n_obs}: meta.json belongs to another run; restore it from the run folder")
    _warn_scene(directory, meta)
    norm = path.parent / NORM_FILE
    vn = _load_norm(norm, n_obs) if norm.exists() else None
    return Policy(directory, model, vn.obs_rms if vn else None, float(vn.clip_obs) if vn else 10.0,
                  float(vn.epsilon) if vn else 1e-8, meta)


def _warn_scene(directory: Path, meta: dict) -> None:
    """Warn when the policy was trained in other scene files or on other target lists than the installed ones."""
    import warnings

    from mjendo import targets
    from mjendo.scene import fingerprint

    task = trained_task(meta)
    if "fidelity" not in task:
        return
    checks = [("scene_fingerprint", "scenes", "the physics changed since",
               lambda: fingerprint(task["fidelity"], int(task["version"]))),
              ("targets_fingerprint", "target lists", "the targets were drawn again since (make targets)",
               lambda: targets.fingerprint(int(task["version"])))]
    for key, what, why, installed in checks:
        trained = meta.get(key)
        if trained is None:
            continue
        try:
            now = installed()
        except (OSError, ConfigError):
            continue
        if now != trained:
            warnings.warn(f"policy {directory} was trained on {what} {trained}, the installed {what} are {now}: "
                          f"{why}; retrain it or check out the commit in its meta.json", RuntimeWarning, stacklevel=3)


def published_variants() -> list[str]:
    """Names of the variants published beside the shipped policies (models/policies/variants/<P>-<variant>/)."""
    root = paths.policies_dir() / "variants"
    return sorted(d.name for d in root.glob("*") if (d / "model.zip").is_file()) if root.is_dir() else []


def resolve(spec: str, others: tuple[str, ...] = ("baseline", "random")) -> Path:
    """'A'..'E' (shipped), a published variant's name ('E-paper-step'), a policy or run folder, or a model.zip
    inside one -> the folder; ``others``: the caller's controllers that are not folders, named in the error."""
    if spec in POLICY_NAMES:
        return paths.policies_dir() / spec
    p = Path(spec)
    if p.suffix == ".zip":
        return p.parent
    if p.is_dir():
        return p
    if spec in published_variants():
        return paths.policies_dir() / "variants" / spec
    raise ConfigError(f"unknown policy {spec!r}; valid: {', '.join((*POLICY_NAMES, *others))}, a published "
                      f"variant ({', '.join(published_variants()) or 'none installed'}), or a policy folder with "
                      "model.zip (e.g. runs/E/seed0)")


def obs_options(directory: Path) -> dict[str, bool]:
    """The observation options (task.OBS_OPTIONS) of the policy in ``directory``: its meta, else its input size."""
    from mjendo.task import OBS_OPTIONS, obs_size

    task = read_meta(directory).get("task", {})
    if "force_obs" in task:
        return {k: bool(task.get(k, False)) for k in OBS_OPTIONS}
    return {k: k == "force_obs" and load(directory).n_obs == obs_size(True) for k in OBS_OPTIONS}


def _torch_state(data: bytes) -> dict:
    """A torch state saved inside an SB3 model.zip (its policy or optimizer member)."""
    import io

    import torch

    return torch.load(io.BytesIO(data), map_location="cpu", weights_only=False)


# The value function's parameters in SB3's ActorCriticPolicy state: acting never reads them.
VALUE_PARAMS = ("mlp_extractor.value_net.", "value_net.")


def slim_copy(src: Path, dest: Path, actor_only: bool = False) -> None:
    """Copy model.zip without the optimizer's moments (two thirds of the file; a shipped policy only acts),
    deflated (SB3 stores its members uncompressed; deflating saves about a tenth). ``actor_only``: the value
    function zeroed too (half of the rest once deflated), for study seeds that are only evaluated."""
    import io
    import zipfile

    import torch

    def rewrite(data: bytes, edit) -> bytes:
        state = _torch_state(data)
        edit(state)
        buf = io.BytesIO()
        torch.save(state, buf)
        return buf.getvalue()

    def zero_value(state: dict) -> None:
        for k, v in state.items():
            if k.startswith(VALUE_PARAMS):
                v.zero_()

    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dest, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as zout:
        for item in zin.infolist():
            data = zin.read(item.filename)
            if item.filename == "policy.optimizer.pth":
                data = rewrite(data, lambda state: state.update(state={}))
            elif item.filename == "policy.pth" and actor_only:
                data = rewrite(data, zero_value)
            item.compress_type = zipfile.ZIP_DEFLATED  # the member's own (stored) method would override the archive's
            zout.writestr(item, data)


def is_actor_only(model: Path) -> bool:
    """Whether a model.zip is an evaluation copy (:func:`slim_copy` ``actor_only``): its value function is zero."""
    import zipfile

    with zipfile.ZipFile(model) as z:
        state = _torch_state(z.read("policy.pth"))
    values = [v for k, v in state.items() if k.startswith(VALUE_PARAMS)]
    return bool(values) and not any(bool(v.any()) for v in values)


def home(policy: str, variant: str | None) -> Path:
    """Where a policy of this variant ships: models/policies/<P>/ for the letter's shipped recipe (the training
    config's ``shipped``, or its paper entry if none), else models/policies/variants/<P>-<variant>/ (a run of
    the paper's entry, variant None, of a letter that ships another recipe: <P>-paper)."""
    from mjendo.train_config import shipped_variant

    shipped = shipped_variant(policy, paths.TRAINING_CONFIG)
    if variant == shipped:
        return paths.policies_dir() / policy
    return paths.policies_dir() / "variants" / f"{policy}-{variant or 'paper'}"


def ship(run: Path, policy: str, dest: Path | None = None, actor_only: bool = False) -> Path:
    """Copy a finished run's final policy into models/policies/<policy>/ (what users get); another variant's run
    (train/policies.yaml's variants) into models/policies/variants/<policy>-<variant>/, beside it.

    Model (without optimizer moments), normalisation, meta and config only: logs stay in the run.
    The run's own meta.json travels with it: what the run used, never today's defaults. Final
    weights, not ``best/``: with the learning rate decayed to 0 the end of the run is the converged
    policy (docs/training.md).
    """
    run = Path(run)
    meta = read_meta(run)
    if not (run / MODEL_FILE).exists() or not meta.get("timesteps"):
        raise PolicyError(f"{run} is not a finished run (no {MODEL_FILE} or no trained steps in {META_FILE}); "
                          "finish it with the same `make train` command first")
    dest = Path(dest) if dest else home(policy, meta.get("training", {}).get("variant"))
    dest.mkdir(parents=True, exist_ok=True)
    for name in (CONFIG_FILE, NORM_FILE):
        if (run / name).exists():
            shutil.copy2(run / name, dest / name)
    last = _last_evaluation(run)
    write_meta(dest, {**meta, "final_evaluation": last} if last else meta)
    slim_copy(run / MODEL_FILE, dest / MODEL_FILE, actor_only)
    return dest


def _last_evaluation(run: Path) -> dict | None:
    """The run's last periodic evaluation (evaluations.csv), so a shipped policy says how well it did."""
    import csv

    path = run / "evaluations.csv"
    if not path.exists():
        return None
    with open(path) as f:
        rows = list(csv.DictReader(f))
    if not rows:
        return None
    last = rows[-1]
    return {"timesteps": int(last["timesteps"]), "success_rate": float(last["success_rate"]),
            "mean_final_mm": float(last["mean_final_mm"])}


def comparison(a: Path, b: Path) -> dict[str, bool]:
    """Whether two policy folders agree, part by part, on what decides how they act: the task, the actor's weights,
    the value function (where both keep one) and the normalisation; all True when a retrained run reproduces a
    published policy bit for bit."""
    import torch

    pa, pb = load(a), load(b)
    sa, sb = pa.model.policy.state_dict(), pb.model.policy.state_dict()

    def same(keys) -> bool:
        return all(k in sb and sa[k].shape == sb[k].shape and torch.equal(sa[k], sb[k]) for k in keys)

    # Resolved, so that a meta written before a task option existed equals one that records the option's default.
    out = {"task": task_config(**trained_task(pa.meta)) == task_config(**trained_task(pb.meta)),
           "actor weights": sa.keys() == sb.keys() and same(k for k in sa if not k.startswith(VALUE_PARAMS))}
    if not any(is_actor_only(model_home(d) / MODEL_FILE) for d in (a, b)):
        out["value function"] = same(k for k in sa if k.startswith(VALUE_PARAMS))
    ra, rb = pa.obs_rms, pb.obs_rms
    out["normalisation"] = (ra is None and rb is None) or (ra is not None and rb is not None and np.array_equal(
        ra.mean, rb.mean) and np.array_equal(ra.var, rb.var))
    return out


def _compare(a: Path, b: Path) -> int:
    parts = comparison(a, b)
    differ = [k for k, same in parts.items() if not same]
    if differ:
        print(f"{a} and {b} differ: {', '.join(differ)}")
        return 1
    print(f"{a} and {b} are the same policy, bit for bit: {', '.join(parts)}")
    return 0


def input_weights(directory: str) -> list[tuple[str, float, float]]:
    """Per observation block: the smallest and largest norm of its inputs' columns in the actor's first layer. An
    input trained from zero weight (mjendo.widen) that kept little of it shows here; `--force-off` measures the
    effect."""
    from mjendo.task import obs_blocks

    pol = load(resolve(directory))
    weight = pol.model.policy.mlp_extractor.policy_net[0].weight.detach().numpy()
    norms, rows, start = np.linalg.norm(weight, axis=0), [], 0
    for name, size, *_ in obs_blocks(**obs_options(pol.directory)):
        rows.append((name, float(norms[start:start + size].min()), float(norms[start:start + size].max())))
        start += size
    return rows


def main(argv: list[str] | None = None) -> int:
    """``python -m mjendo.artifacts ship RUN POLICY`` (``make ship``): copy a finished run's policy;
    ``compare RUN FOLDER``: whether a retrained run reproduced a published policy (exit status 1 if not)."""
    import argparse

    from mjendo import cli

    ap = argparse.ArgumentParser(prog="python -m mjendo.artifacts", description=main.__doc__)
    sub = ap.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("ship", help="copy a finished run to models/policies/<POLICY>/")
    s.add_argument("run", type=Path, help="run folder, e.g. runs/E/seed0")
    s.add_argument("policy", choices=POLICY_NAMES)
    s.add_argument("--actor-only", action="store_true", help="an evaluation copy: the value function zeroed, half "
                   "the bytes, the same actions; no run can continue from it")
    c = sub.add_parser("compare", help="whether two policy folders act alike bit for bit (a retrain and its "
                       "published seed)")
    c.add_argument("run", type=Path, help="a policy folder, e.g. runs/E/paired-fast-coarse-seed4-fast-coarse")
    c.add_argument("folder", type=Path, help="another, e.g. models/policies/E/seeds/seed4")
    w = sub.add_parser("inputs", help="how much weight the actor's first layer gives each observation block")
    w.add_argument("folder", help="a policy folder or name, e.g. E or models/policies/variants/E-paper")
    a = ap.parse_args(argv)
    if a.cmd == "inputs":
        return cli.run(lambda: print("\n".join(f"{name:24s} {lo:6.3f} - {hi:6.3f}"
                                               for name, lo, hi in input_weights(a.folder))), PolicyError, ConfigError)
    if a.cmd == "compare":
        status = []
        code = cli.run(lambda: status.append(_compare(a.run, a.folder)), PolicyError)
        return code or status[0]
    return cli.run(lambda: print(f"shipped {a.run} to {ship(a.run, a.policy, actor_only=a.actor_only)}"), PolicyError)


if __name__ == "__main__":
    raise SystemExit(main())
