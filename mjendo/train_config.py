"""The training configuration: dataclasses with one docstring per field, loaded from train/policies.yaml.

The YAML has ``defaults`` and one entry per policy under ``policies``; an
entry overrides any default, its ``ppo:``, ``task:`` and ``finetune:`` blocks
are merged key by key into the defaults' blocks. The values live in the YAML
only (the dataclasses document and type them); unknown or missing keys and
values of the wrong type are refused with the file and the key named, so a typo
cannot silently train something else (CleanRL's ``Args`` style).
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import yaml

from mjendo.config import CONDITIONS, FIDELITIES, POLICY_NAMES, ConfigError, TaskConfig, task_config
from mjendo.sampling import SAMPLINGS

TASK_KEYS_SET_BY_POLICY = ("env", "fidelity", "force_obs")  # top-level fields of a policy entry


@dataclass
class PPOArgs:
    """Stable-Baselines3 PPO arguments (paper: PPO; values it does not give are SB3/zoo defaults)."""

    learning_rate: float
    """initial learning rate"""
    lr_schedule: str
    """'linear' (decays to 0 at total_timesteps) or 'constant'"""
    n_steps: int
    """steps per environment per update"""
    batch_size: int
    """minibatch size"""
    n_epochs: int
    """passes over each rollout"""
    gamma: float
    """discount factor"""
    gae_lambda: float
    """GAE lambda"""
    clip_range: float
    """PPO clipping"""
    ent_coef: float
    """entropy bonus weight"""
    net_arch: list[int]
    """hidden layers of policy and value MLPs (paper: [256, 128, 64, 32])"""
    log_std_init: float
    """initial log standard deviation of the Gaussian policy"""
    weight_decay: float = 0.0
    """L2 penalty on the networks' weights (Adam's coupled weight_decay): the regulariser that narrowed the gap to
    held-out levels most in Cobbe et al. 2019 (ICML, "Quantifying generalization in RL"); 0 in the paper"""

    def check(self) -> None:
        if self.lr_schedule not in ("linear", "constant"):
            raise ConfigError(f"ppo.lr_schedule must be 'linear' or 'constant', not {self.lr_schedule!r}")
        for name in ("n_steps", "batch_size", "n_epochs"):
            if getattr(self, name) < 1:
                raise ConfigError(f"ppo.{name} must be >= 1")
        if not (self.learning_rate > 0 and 0 < self.gamma <= 1 and 0 <= self.gae_lambda <= 1
                and self.clip_range > 0 and self.ent_coef >= 0 and self.weight_decay >= 0):
            raise ConfigError("ppo: learning_rate and clip_range must be > 0, gamma in (0, 1], gae_lambda in "
                              "[0, 1], ent_coef and weight_decay >= 0")
        if not self.net_arch or min(self.net_arch) < 1:
            raise ConfigError("ppo.net_arch must list positive layer widths, e.g. [256, 128, 64, 32]")


@dataclass
class FinetuneArgs:
    """What changes when a run starts from a trained policy (``--init-from``)."""

    fidelity: str
    """stomach to continue in"""
    total_timesteps: int
    """budget of the fine-tuning run"""
    learning_rate: float
    """initial learning rate of the fine-tuning run"""


@dataclass
class BatchedArgs:
    """What changes when a run trains on the batched MuJoCo Warp backend (``--backend warp``)."""

    n_envs: int
    """worlds stepped together on the device"""
    total_timesteps: int
    """budget: large batches need more samples than 2 CPU environments"""
    ppo: dict[str, Any] = field(default_factory=dict)
    """PPO fields that change with large batches (n_steps, batch_size, n_epochs, learning_rate, ...)"""
    eval_every: int | None = None
    """steps between periodic evaluations (in the CPU env: at GPU rates every 20k steps would dominate)"""
    checkpoint_every: int | None = None
    """steps between checkpoints"""


@dataclass
class TrainConfig:
    """One policy's resolved training run."""

    policy: str
    """A-E (paper's five policies)"""
    env: str
    """condition trained in: FE, SE, DE, UE1, UE2"""
    force_obs: bool
    """observe the contact indicator and force (policies C and E)"""
    fidelity: str
    """stomach: 'fast' (reduced order) or 'full' (per-vertex FEM)"""
    seed: int
    """training seed; the run folder is seed<N>"""
    n_envs: int
    """parallel environments"""
    vec_env: str
    """'dummy' (one process) or 'subproc' (one process per environment)"""
    total_timesteps: int
    """budget in environment steps"""
    checkpoint_every: int
    """steps between checkpoints (a killed run loses at most this much)"""
    eval_every: int
    """steps between periodic evaluations"""
    eval_episodes: int
    """80-step evaluation trials per periodic evaluation"""
    normalize: bool
    """VecNormalize observations and rewards"""
    ppo: PPOArgs
    """PPO arguments"""
    finetune: FinetuneArgs
    """the fine-tuning block, applied with init_from"""
    batched: BatchedArgs
    """the batched-backend block, applied with backend 'warp'"""
    backend: str = "cpu"
    """'cpu' (MuJoCo, one process per environment group) or 'warp' (MuJoCo Warp: all worlds on one device)"""
    task: dict[str, Any] = field(default_factory=dict)
    """TaskConfig fields other than env/fidelity/force_obs (action scales, max_steps, force_penalty, ...)"""
    init_from: str | None = None
    """policy folder to start from (fine-tuning), or None"""
    variant: str | None = None
    """name of the config's variants entry this run applies to its policy (its shipped recipe by default), or
    None (the paper's entry)"""
    curriculum_steps: int = 0
    """steps over which contact-aided targets go from never drawn to drawn as often as the others (0: none)"""
    train_targets: str | None = None
    """the targets training draws from: None (the env's own list, the paper) or lists joined by '+', e.g.
    'A+F' (list A and the free-space targets, each list drawn equally often); evaluations use the env's list"""
    target_sampling: str = "uniform"
    """how training draws targets: 'uniform' (the paper) or 'adaptive' (more often the less reliably the policy
    reaches them within a trial; mjendo.sampling). The batched backend draws uniformly"""
    guide_steps: int = 0
    """episodes aimed at a contact-aided target begin with up to this many steps of the map's demonstrator, drawn
    uniformly from 0 (0: none; mjendo.demonstrations); the maximum falls linearly to 0 at guide_decay_steps"""
    guide_decay_steps: int = 0
    """steps after which training is unguided (0: the whole budget)"""
    widen_scale: float = 0.0
    """an init_from that observes less: the new inputs' first-layer weights drawn at this share of the spread of the
    old inputs' (normal, per layer); 0 keeps the source's function exactly (mjendo.widen), above 0 starts the new
    inputs at a weight the policy can lean on"""
    full_envs: int = 0
    """of the n_envs training environments, how many run in the full FEM stomach (the rest in `fidelity`, at the
    same task and physics step): samples from the model of record at a fraction of its cost; periodic
    evaluations stay in `fidelity`"""
    critic_only: list[str] = field(default_factory=list)
    """observation options (scope_obs, time_obs, phase_obs; on in the task block too) whose blocks only the value
    function sees: an asymmetric actor-critic (mjendo.asymmetric); the policy acts on the rest"""
    critic_warmup_steps: int = 0
    """steps at the start of the run in which only the value function learns (the actor frozen): a fine-tune in
    another stomach otherwise takes its first actor steps on advantages from a critic fitted to the old one"""
    freeze_normalization: bool = False
    """keep the observation and reward statistics the run starts with (its init_from's): in another stomach
    adapting them moves every input the policy reads while the policy itself has not yet learnt anything there"""

    @property
    def rollout_size(self) -> int:
        """Samples PPO collects per update: every environment's n_steps."""
        return self.n_envs * self.ppo.n_steps

    def task_config(self) -> TaskConfig:
        """The task this run trains in (validated)."""
        return task_config(env=self.env, fidelity=self.fidelity, force_obs=self.force_obs, **self.task)

    def check(self) -> None:
        if self.policy not in POLICY_NAMES:
            raise ConfigError(f"unknown policy {self.policy!r}; valid: {', '.join(POLICY_NAMES)}")
        if self.env not in CONDITIONS or self.fidelity not in FIDELITIES:
            raise ConfigError(f"policy {self.policy}: env must be one of {', '.join(CONDITIONS)} and fidelity one "
                              f"of {', '.join(FIDELITIES)}")
        if self.backend not in ("cpu", "warp"):
            raise ConfigError(f"backend must be 'cpu' or 'warp', not {self.backend!r}")
        if self.vec_env not in ("dummy", "subproc"):
            raise ConfigError(f"vec_env must be 'subproc' or 'dummy', not {self.vec_env!r}")
        if self.n_envs < 1:
            raise ConfigError(f"n_envs must be >= 1 (got {self.n_envs})")
        if self.seed < 0:
            raise ConfigError(f"seed must be >= 0 (got {self.seed}); seeds name run folders (seed<N>)")
        if self.total_timesteps < 1:
            raise ConfigError(f"total_timesteps must be >= 1 (got {self.total_timesteps}): a run that trains no "
                              "step would be marked finished and could be shipped")
        if self.curriculum_steps < 0 or (self.curriculum_steps and self.backend == "warp"):
            raise ConfigError(f"curriculum_steps must be >= 0 and needs the cpu backend (got {self.curriculum_steps}, "
                              f"backend {self.backend})")
        if self.target_sampling not in SAMPLINGS:
            raise ConfigError(f"target_sampling must be one of {', '.join(SAMPLINGS)}, not {self.target_sampling!r}")
        if self.guide_steps < 0 or self.guide_decay_steps < 0 or (self.guide_steps and self.backend == "warp"):
            raise ConfigError(f"guide_steps and guide_decay_steps must be >= 0, and guided starts need the cpu "
                              f"backend (got {self.guide_steps}, {self.guide_decay_steps}, backend {self.backend})")
        if self.guide_steps and self.task_config().version < 1:
            raise ConfigError("guided starts replay the reachability map's demonstrators, which task version 0 "
                              "(vertex targets) has none of: use version 1 or guide_steps 0")
        if not (isinstance(self.widen_scale, int | float) and 0 <= self.widen_scale <= 10):
            raise ConfigError(f"widen_scale must be a number from 0 (the new inputs at zero weight) to 10, not "
                              f"{self.widen_scale!r}")
        if not 0 <= self.full_envs <= self.n_envs or (self.full_envs and self.backend == "warp"):
            raise ConfigError(f"full_envs must be between 0 and n_envs ({self.n_envs}) and needs the cpu backend "
                              f"(got {self.full_envs}, backend {self.backend})")
        if self.full_envs:
            task_config(env=self.env, fidelity="full", force_obs=self.force_obs, **self.task)
        if self.critic_only:
            from mjendo.asymmetric import actor_inputs

            if self.backend == "warp":
                raise ConfigError("critic_only needs the cpu backend (its inputs are not in the batched observation)")
            actor_inputs(self.task_config(), self.critic_only)
        if self.critic_warmup_steps < 0:
            raise ConfigError(f"critic_warmup_steps must be >= 0 (got {self.critic_warmup_steps})")
        for name in ("checkpoint_every", "eval_every", "eval_episodes"):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name} must be >= 1")
        unknown = set(self.task) - {f.name for f in fields(TaskConfig)}
        if unknown or set(self.task) & set(TASK_KEYS_SET_BY_POLICY + ("target_list",)):
            raise ConfigError(f"task block: unknown or not settable keys {sorted(unknown or self.task)}; valid: "
                              + ", ".join(f.name for f in fields(TaskConfig)
                                          if f.name not in TASK_KEYS_SET_BY_POLICY + ("target_list",)))
        self.ppo.check()
        self.task_config()
        if self.train_targets is not None:
            if self.backend == "warp":
                raise ConfigError("train_targets needs the cpu backend (the batched worlds draw the env's list): "
                                  "train this recipe with --backend cpu, or the paper's with --variant paper")
            task_config(env=self.env, fidelity=self.fidelity, target_list=self.train_targets)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


# ------------------------------------------------------------------ loading
def _typename(tp) -> str:
    return getattr(tp, "__name__", str(tp))


_SCALARS = {
    bool: (lambda v: isinstance(v, bool), "true or false"),
    int: (lambda v: isinstance(v, int) and not isinstance(v, bool), "a whole number"),
    float: (lambda v: isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v), "a finite number"),
    str: (lambda v: isinstance(v, str), "a string"),
}


def _coerce(value, tp, where: str):
    """``value`` as type ``tp`` (a dataclass, list[int], X | None, bool, int, float, str, dict), or ConfigError."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        return _coerce(value, next(a for a in args if a is not type(None)), where)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(f"{where} must be a mapping of {_typename(tp)} fields, not {value!r}")
        return from_dict(tp, value, where)
    if origin is list:
        (item,) = typing.get_args(tp)
        if not isinstance(value, list):
            raise ConfigError(f"{where} must be a list, not {value!r}")
        return [_coerce(v, item, f"{where}[{i}]") for i, v in enumerate(value)]
    if origin is dict or tp is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{where} must be a mapping, not {value!r}")
        return dict(value)
    if tp in _SCALARS:
        ok, what = _SCALARS[tp]
        if not ok(value):
            raise ConfigError(f"{where} must be {what}, not {value!r}")
        return float(value) if tp is float else value
    return value


def from_dict(cls, data: dict, where: str):
    """A dataclass from a mapping: unknown, missing or mistyped keys are a ConfigError naming them."""
    hints = typing.get_type_hints(cls)
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(unknown)}; valid: {', '.join(sorted(known))}")
    required = {f.name for f in fields(cls)
                if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING}
    missing = sorted(required - set(data))
    if missing:
        raise ConfigError(f"{where}: missing key(s) {', '.join(missing)}")
    return cls(**{k: _coerce(v, hints[k], f"{where}.{k}") for k, v in data.items()})


def _merge(base: dict, over: dict) -> dict:
    """Entry over defaults; the ppo/task/finetune blocks merge key by key."""
    out = dict(base)
    for k, v in over.items():
        out[k] = {**out[k], **v} if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def read_yaml(path: Path) -> dict:
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"training config {path} does not exist")
    try:
        raw = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(f"training config {path} is not valid YAML: {' '.join(str(exc).split())}") from exc
    if not isinstance(raw, dict) or not isinstance(raw.get("policies"), dict):
        raise ConfigError(f"training config {path} must be a YAML mapping with 'defaults' and 'policies' "
                          "(see train/policies.yaml)")
    if not isinstance(raw.get("defaults", {}), dict):
        raise ConfigError(f"training config {path}: 'defaults' must be a mapping")
    return raw


def _variant(raw: dict, path: Path, policy: str, variant: str) -> dict:
    """A variants entry of the config (its ``policy``, one or a list, must hold the one trained), without that key."""
    variants = raw.get("variants") or {}
    block = variants.get(variant)
    if not isinstance(block, dict):
        raise ConfigError(f"training config {path} has no variant {variant!r}; valid: {', '.join(variants) or 'none'}")
    allowed = block.get("policy") if isinstance(block.get("policy"), list) else [block.get("policy")]
    if policy not in allowed:
        raise ConfigError(f"variant {variant} is a variant of policy {' or '.join(map(str, allowed))}, not {policy}: "
                          f"use --policy {allowed[0]}")
    return {k: v for k, v in block.items() if k != "policy"}


def shipped_variant(policy: str, path: Path) -> str | None:
    """The variant a letter trains and ships by default (the config's ``shipped``), or None: its paper entry."""
    return _shipped(read_yaml(path), path, policy)


def _shipped(raw: dict, path: Path, policy: str) -> str | None:
    shipped = raw.get("shipped") or {}
    if not isinstance(shipped, dict) or not all(isinstance(v, str) for v in shipped.values()):
        raise ConfigError(f"training config {path}: 'shipped' must map policy letters to variant names")
    return shipped.get(policy)


def load(policy: str, path: Path, variant: str | None = None, **overrides) -> TrainConfig:
    """The resolved, validated config of one policy: defaults, its entry, fine-tuning block, then overrides.

    Without ``variant`` the letter's shipped recipe (:func:`shipped_variant`) applies, if the config names one.
    ``overrides`` are command-line values (None: not given); ``learning_rate``
    goes into the ppo block, ``init_from`` switches on the finetune block.
    """
    if policy not in POLICY_NAMES:
        raise ConfigError(f"unknown policy {policy!r}; valid: {', '.join(POLICY_NAMES)}")
    raw = read_yaml(path)
    entry = raw["policies"].get(policy)
    if not isinstance(entry, dict):
        raise ConfigError(f"training config {path} has no entry for policy {policy} under 'policies'")
    merged = _merge(raw.get("defaults") or {}, entry)
    variant = variant or _shipped(raw, path, policy)
    if variant is not None:
        merged = {**_merge(merged, _variant(raw, path, policy, variant)), "variant": variant}
    merged["policy"] = policy
    cfg = from_dict(TrainConfig, merged, f"{Path(path).name} policy {policy}")
    given = {k: v for k, v in overrides.items() if v is not None}
    if given.get("init_from") is not None:
        ft = cfg.finetune
        cfg.fidelity, cfg.total_timesteps = ft.fidelity, ft.total_timesteps
        cfg.ppo.learning_rate = ft.learning_rate
        cfg.init_from = str(given["init_from"])
    if given.pop("backend", "cpu") == "warp":
        cfg.backend = "warp"
        cfg.target_sampling = "uniform"  # its worlds draw their targets on the device
        cfg.n_envs, cfg.total_timesteps = cfg.batched.n_envs, cfg.batched.total_timesteps
        cfg.eval_every = cfg.batched.eval_every or cfg.eval_every
        cfg.checkpoint_every = cfg.batched.checkpoint_every or cfg.checkpoint_every
        cfg.ppo = from_dict(PPOArgs, {**dataclasses.asdict(cfg.ppo), **cfg.batched.ppo}, "batched.ppo")
    if "learning_rate" in given:
        cfg.ppo.learning_rate = _coerce(given.pop("learning_rate"), float, "--learning-rate")
    given.pop("init_from", None)
    hints = typing.get_type_hints(TrainConfig)
    for k, v in given.items():
        setattr(cfg, k, _coerce(v, hints[k], f"--{k.replace('_', '-')}"))
    cfg.check()
    return cfg
