"""Training end to end (a few hundred steps), resume, policy loading and bad input."""

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest

import mjendo
from mjendo import artifacts
from mjendo.config import ConfigError
from mjendo.envs import EndoscopeEnv
from mjendo.paths import TRAINING_CONFIG
from mjendo.policies import PolicyError, PPOController, load_controller
from mjendo.scene import fingerprint
from mjendo.task import OBS_OPTIONS, NavigationTask
from mjendo.train import latest_checkpoint, load_config, make_env, run_folder, target_sampler, train
from mjendo.train_config import shipped_variant


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs")
    # Tiny budget: 2 envs x 64 steps per update, checkpoint and evaluate often.
    import yaml

    raw = yaml.safe_load(TRAINING_CONFIG.read_text())
    raw["defaults"].update(checkpoint_every=128, eval_every=256, eval_episodes=1, vec_env="dummy", n_envs=2)
    raw["defaults"]["ppo"].update(n_steps=64, batch_size=64, n_epochs=1)
    cfg_path = out / "policies.yaml"
    cfg_path.write_text(yaml.safe_dump({**raw, "shipped": {}}))  # the paper's entries: runs from scratch
    (out / "shipped.yaml").write_text(yaml.safe_dump(raw))
    run = train("D", timesteps=256, out=out, config_file=cfg_path)
    resumed = train("D", timesteps=512, out=out, config_file=cfg_path)
    return run, resumed


def test_fine_tuning_starts_from_the_policy_and_counts_its_own_steps(short_run, tmp_path):
    import torch
    from stable_baselines3 import PPO

    src, _ = short_run
    cfg_path = src.parent.parent / "policies.yaml"
    # Two updates: with the linear schedule the last update of a run has a learning rate of 0.
    run = train("D", timesteps=256, out=tmp_path, config_file=cfg_path, fidelity="fast", init_from=src,
                learning_rate=1e-3)
    meta = json.loads((run / "meta.json").read_text())
    assert run.name == "seed0" and meta["init_from"] == str(src) and meta["timesteps"] == 256
    assert meta["training"]["ppo"]["learning_rate"] == 1e-3
    before, after = (PPO.load(str(d / "model.zip"), device="cpu").policy.state_dict() for d in (src, run))
    changed = [k for k in before if not torch.equal(before[k], after[k])]
    assert changed, "fine-tuning did not update the weights"
    # ... starting from them: two updates move every weight matrix a little, not to a fresh initialisation.
    mats = [k for k in before if before[k].ndim == 2]
    assert all(torch.norm(after[k] - before[k]) < 0.5 * torch.norm(before[k]) for k in mats)
    with pytest.raises(ConfigError, match="holds no model.zip"):
        train("D", timesteps=128, out=tmp_path / "x", config_file=cfg_path, init_from=tmp_path / "nothing")


def test_a_variant_starting_from_a_shipped_policy_finds_it_from_any_directory(short_run, tmp_path, monkeypatch):
    # free-pool-then-A names its start as a path inside mjendo's data: it must not depend on the working directory.
    import torch
    from stable_baselines3 import PPO

    cfg_path = short_run[0].parent.parent / "policies.yaml"
    monkeypatch.chdir(tmp_path)
    run = train("E", timesteps=128, out=tmp_path / "runs", config_file=cfg_path, variant="free-pool-then-A",
                progress=False)
    meta = json.loads((run / "meta.json").read_text())
    assert run.name == "free-pool-then-A-seed0" and meta["training"]["fidelity"] == "fast"
    assert meta["init_from"] == "models/policies/variants/E-free-pool" and meta["training"]["train_targets"] is None
    assert meta["timesteps"] == 128  # the run's own PPO settings (64 steps per env), not the source's 1024
    src = mjendo.paths.DATA / meta["init_from"]
    before, after = (PPO.load(str(d / "model.zip"), device="cpu").policy.state_dict() for d in (src, run))
    mats = [k for k in before if before[k].ndim == 2]
    assert all(torch.norm(after[k] - before[k]) < 0.05 * torch.norm(before[k]) for k in mats)


def test_fine_tunes_of_one_policy_with_different_seeds_differ(short_run, tmp_path):
    # PPO.load re-seeded every fine-tune with the source's seed: seeds 1 and 2 trained the same policy (two
    # updates: the last one of a run has a learning rate of 0).
    import torch
    from stable_baselines3 import PPO

    src, _ = short_run
    cfg_path = src.parent.parent / "policies.yaml"
    runs = {s: train("D", timesteps=256, seed=s, out=tmp_path, config_file=cfg_path, init_from=src, fidelity="fast",
                     progress=False) for s in (1, 2)}
    first = {s: (r / "episodes.csv").read_text().splitlines()[1:4] for s, r in runs.items()}
    assert first[1] != first[2]
    weights = {s: PPO.load(str(r / "model.zip"), device="cpu").policy.state_dict() for s, r in runs.items()}
    assert any(not torch.equal(weights[1][k], weights[2][k]) for k in weights[1])
    assert PPO.load(str(runs[2] / "model.zip"), device="cpu").seed == 2


def test_a_fine_tune_with_another_discount_uses_it_everywhere(short_run, tmp_path):
    # short-horizon continues a policy trained at 0.99 with 0.98: PPO and the reward normalisation both switch.
    import pickle

    from stable_baselines3 import PPO

    cfg_path = short_run[0].parent.parent / "policies.yaml"
    run = train("E", timesteps=128, out=tmp_path, config_file=cfg_path, variant="short-horizon", progress=False)
    assert PPO.load(str(run / "model.zip"), device="cpu").gamma == pytest.approx(0.98)
    with open(run / "vecnormalize.pkl", "rb") as f:
        assert pickle.load(f).gamma == pytest.approx(0.98)
    source = mjendo.paths.DATA / "models/policies/variants/E-free-pool-then-A/vecnormalize.pkl"
    with open(source, "rb") as f:
        assert pickle.load(f).gamma == pytest.approx(0.99)  # what it would have kept


def test_fine_tune_config_block_applies_only_with_init_from(tmp_path):
    assert load_config("E", TRAINING_CONFIG, "paper").fidelity == "fast"
    ft = load_config("E", TRAINING_CONFIG, init_from="models/policies/E")
    assert ft.fidelity == "full" and ft.ppo.learning_rate == pytest.approx(1e-4)
    assert ft.total_timesteps == 100000 and ft.init_from == "models/policies/E"


def test_batched_block_applies_only_with_the_warp_backend():
    cpu, gpu = load_config("E", TRAINING_CONFIG, "paper"), load_config("E", TRAINING_CONFIG, "paper", backend="warp")
    with pytest.raises(ConfigError, match="train_targets needs the cpu backend.*--variant paper"):
        load_config("E", TRAINING_CONFIG, backend="warp")  # the shipped recipe draws lists A and F
    assert (cpu.backend, cpu.n_envs, cpu.rollout_size, cpu.eval_every) == ("cpu", 8, 2048, 50000)
    # 4096 worlds fill a 131k-sample rollout: evaluating (in the CPU env) every 50k steps would follow each one
    assert gpu.backend == "warp" and gpu.n_envs == 4096 and gpu.ppo.batch_size == 32768
    assert gpu.eval_every >= 10 * gpu.n_envs * gpu.ppo.n_steps and gpu.checkpoint_every > cpu.checkpoint_every


def test_make_train_runs_the_shipped_recipe_from_its_committed_start(short_run):
    """`make train POLICY=E` on a fresh clone: E continues the committed D start, widened to the force inputs."""
    out = short_run[0].parent.parent
    run = train("E", timesteps=128, out=out, config_file=out / "shipped.yaml", progress=False)
    meta = json.loads((run / "meta.json").read_text())
    assert run.name == "paired-fast-coarse-seed0-fast-coarse" and meta["timesteps"] == 128
    assert meta["init_from"] == "models/policies/variants/D-guided-free-pool" and meta["task"]["force_obs"]
    assert meta["task"]["fidelity"] == "fast-coarse" and meta["training"]["variant"] == "paired-fast-coarse"


def test_short_training_writes_a_loadable_policy(short_run):
    run, _ = short_run
    for name in ("model.zip", "vecnormalize.pkl", "meta.json", "config.yaml", "episodes.csv",
                 "evaluations.csv", "curve.png", "best/model.zip", "best/vecnormalize.pkl", "best/meta.json"):
        assert (run / name).exists(), name
    assert json.loads((run / "best" / "meta.json").read_text())["timesteps"] in (256, 512)
    ctrl = PPOController.from_folder(run)
    env = EndoscopeEnv("DE", force_obs=False)
    obs, _ = env.reset(seed=0)
    ctrl.reset(env.task)
    a = ctrl.act(obs, env.task)
    assert a.shape == (5,) and np.all(np.abs(a) <= 0.4 + 1e-6)
    env.step(a)
    with pytest.raises(PolicyError, match="expects 11 observations"):
        ctrl.check(EndoscopeEnv("DE", force_obs=True).task)
    # The run records the task it trained in and what its inputs mean; a task with other scales is refused.
    meta = json.loads((run / "meta.json").read_text())
    assert {k: meta["task"][k] for k in ("env", "force_obs", "version", "control_period_s", "cable_mm_per_unit",
                                         "insertion_mm_per_unit")} == {
        "env": "DE", "force_obs": False, "version": 1, "control_period_s": 0.1, "cable_mm_per_unit": 1.0,
        "insertion_mm_per_unit": 6.25}
    # Provenance: the code, the scenes and the command as typed (not an interpreter's path).
    assert meta["mjendo_version"] == mjendo.__version__ and meta["scene_fingerprint"] == fingerprint("fast")
    assert meta["commit"] is None or len(meta["commit"].split("+")[0]) == 40
    assert meta["command"].startswith("python -m mjendo.train")
    assert [b["name"] for b in meta["observation"]] == ["ee_to_target", "ee_velocity", "cable_lengths",
                                                        "previous_axial_action"]
    with pytest.raises(PolicyError, match="insertion_mm_per_unit 6.25 \\(task: 5.0\\)"):
        ctrl.check(NavigationTask(env="DE", force_obs=False, insertion_mm_per_unit=5.0))
    with pytest.raises(PolicyError, match="trained in task version 1, the task is version 0"):
        ctrl.check(NavigationTask(env="DE", force_obs=False, version=0))


def test_shipping_keeps_the_policy_and_drops_the_optimizer(short_run, tmp_path):
    run, _ = short_run
    dest = artifacts.ship(run, "D", tmp_path / "D")
    assert {p.name for p in dest.iterdir()} == {"config.yaml", "meta.json", "model.zip", "vecnormalize.pkl"}
    # The shipped meta says how the run's last periodic evaluation went (512 steps: evaluated at 256 and 512).
    last = json.loads((dest / "meta.json").read_text())["final_evaluation"]
    assert last["timesteps"] == 512 and 0.0 <= last["success_rate"] <= 1.0 and last["mean_final_mm"] > 0
    assert (dest / "model.zip").stat().st_size < 0.6 * (run / "model.zip").stat().st_size
    import zipfile

    with zipfile.ZipFile(dest / "model.zip") as z:  # deflated, not SB3's stored members
        assert {i.compress_type for i in z.infolist()} == {zipfile.ZIP_DEFLATED}
    env = EndoscopeEnv("DE", force_obs=False)
    obs, _ = env.reset(seed=0)
    np.testing.assert_array_equal(PPOController.from_folder(dest).act(obs, env.task),
                                  PPOController.from_folder(run).act(obs, env.task))


def test_resume_continues_the_step_count(short_run):
    run, resumed = short_run
    assert resumed == run
    meta = json.loads((run / "meta.json").read_text())
    assert meta["timesteps"] == 512
    assert latest_checkpoint(run) is not None
    sampler = target_sampler(load_config("D", run.parent.parent / "policies.yaml"), run)  # D draws adaptively
    saved = json.loads((latest_checkpoint(run).parent / "sampling_512.json").read_text())
    assert saved["targets"] == sampler.targets and np.allclose(saved["solved"], sampler.solved)
    assert len(sampler.targets) > 40 and sampler.solved.max() <= 1.0
    steps = np.loadtxt(run / "episodes.csv", delimiter=",", skiprows=1, ndmin=2)[:, 0]
    assert np.all(np.diff(steps) >= 0)  # one monotone log across the resume


@pytest.mark.parametrize("broken", ["model_512.zip", "vecnormalize_512.pkl"])
def test_unreadable_checkpoint_is_named_on_resume(short_run, tmp_path, broken):
    run, _ = short_run
    copy = tmp_path / "D" / run.name
    shutil.copytree(run, copy)
    (latest_checkpoint(copy).parent / broken).write_bytes(b"truncated by a crash")
    with pytest.raises(ConfigError, match=r"model_512.zip \(with vecnormalize_512.pkl\) is unreadable .*--fresh"):
        train("D", timesteps=1024, out=tmp_path, config_file=run.parent.parent / "policies.yaml")


def test_bad_policy_value_fails_fast():
    with pytest.raises(ConfigError, match="valid: A, B, C, D, E"):
        load_config("F", TRAINING_CONFIG)
    res = subprocess.run([sys.executable, "-m", "mjendo.train", "--policy", "Q"], capture_output=True, text=True)
    assert res.returncode == 2 and "unknown policy 'Q'" in res.stderr


def test_missing_and_corrupt_policy_files(tmp_path):
    with pytest.raises(PolicyError, match="no policy file"):
        PPOController.from_folder(tmp_path)
    (tmp_path / "model.zip").write_bytes(b"not a zip")
    with pytest.raises(PolicyError, match="corrupt"):
        PPOController.from_folder(tmp_path)
    with pytest.raises(ConfigError, match="unknown policy"):
        load_controller("Z")


def test_unwritable_run_folder(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(ConfigError, match="cannot write the run folder"):
        train("E", timesteps=8, out=blocker)


@pytest.mark.slow  # a PPO throughput figure: timing belongs to `make bench`, not the default suite
def test_bench_training_figure_builds_the_shipped_ppo(tmp_path, monkeypatch):
    # The bench must time the same PPO that training builds (it once broke on a new config key), and leave no
    # empty SB3 log folder in the temp directory per call.
    import tempfile

    from mjendo.bench import training_figure

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    r = training_figure("dummy", 2048, n_envs=2)
    assert r["n_envs"] == 2 and r["steps_per_s"] > 20
    assert not list(tmp_path.glob("SB3-*"))


def _cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "mjendo.train", *args], capture_output=True, text=True, cwd=cwd)


@pytest.mark.parametrize("args,message", [
    (["--n-envs", "0"], "n_envs must be >= 1"),
    (["--seed", "-1"], "seed must be >= 0"),
    (["--timesteps", "0"], "total_timesteps must be >= 1"),
])
def test_training_cli_refuses_bad_arguments_in_one_line(args, message, tmp_path):
    res = _cli("--policy", "E", "--out", str(tmp_path), *args)
    assert res.returncode == 2 and message in res.stderr and "Traceback" not in res.stderr
    assert not list(tmp_path.rglob("model.zip"))  # nothing that looks like a finished run


@pytest.mark.parametrize("text,message", [
    ("defaults: {}\n", "must be a YAML mapping with 'defaults' and 'policies'"),
    ("[not, a, mapping", "is not valid YAML"),
    ("- a list\n", "must be a YAML mapping"),
])
def test_broken_training_config_files(tmp_path, text, message):
    path = tmp_path / "policies.yaml"
    path.write_text(text)
    res = _cli("--policy", "E", "--config", str(path), "--out", str(tmp_path))
    assert res.returncode == 2 and message in res.stderr and "Traceback" not in res.stderr


def _yaml_with(tmp_path, edit):
    import yaml

    raw = yaml.safe_load(TRAINING_CONFIG.read_text())
    edit(raw)
    path = tmp_path / "policies.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


@pytest.mark.parametrize("edit,message", [
    (lambda r: r["defaults"].update(learnin_rate=1e-3), "unknown key.*learnin_rate"),
    (lambda r: r["defaults"]["ppo"].update(n_step=64), r"ppo: unknown key.*n_step"),
    (lambda r: r["defaults"]["ppo"].update(n_steps="64"), "ppo.n_steps must be a whole number"),
    (lambda r: r["policies"]["E"].update(force_obs="yes"), "force_obs must be true or false"),
    (lambda r: r["defaults"].pop("eval_every"), "missing key.*eval_every"),
    (lambda r: r["policies"]["E"].update(task={"insertion_mm": 5}), "task block: unknown"),
    (lambda r: r["policies"]["E"].update(task={"force_penalty": -1.0}), "force_penalty must be"),
    (lambda r: r["defaults"]["ppo"].update(lr_schedule="cosine"), "lr_schedule must be"),
    (lambda r: r["defaults"].update(full_envs=9), r"full_envs must be between 0 and n_envs \(8\)"),
])
def test_training_config_is_validated(tmp_path, edit, message):
    with pytest.raises(ConfigError, match=message):
        load_config("E", _yaml_with(tmp_path, edit))


def test_a_variant_merges_over_its_policy_and_names_its_run(tmp_path):
    cfg = load_config("E", TRAINING_CONFIG, "scope-curriculum")
    assert cfg.variant == "scope-curriculum" and cfg.curriculum_steps > 0 and cfg.task_config().scope_obs
    assert cfg.task_config().force_obs and cfg.env == "DE"  # E's own entry still applies
    assert run_folder(cfg, tmp_path, None) == tmp_path / "E" / "scope-curriculum-seed0"
    assert load_config("E", TRAINING_CONFIG, "paper").curriculum_steps == 0  # the paper's E has none
    # Without --variant a letter trains its shipped recipe (the config's shipped), which is a variant too; the
    # paper's entry alone is the variant paper; a letter without a shipped recipe trains its entry.
    shipped = load_config("E", TRAINING_CONFIG)
    assert shipped.variant == shipped_variant("E", TRAINING_CONFIG) == "paired-fast-coarse"
    assert shipped.init_from and shipped.total_timesteps == 300_000 and shipped.task_config().force_obs
    paper = load_config("E", TRAINING_CONFIG, "paper")
    assert paper.init_from is None and paper.total_timesteps == 1_000_000 and paper.fidelity == "fast"
    assert load_config("A", TRAINING_CONFIG).variant is None
    # B and C train in the one-cell stomach the shipped D and E train in (evaluated, as all are, in `fast`)
    assert [load_config(p, TRAINING_CONFIG).fidelity for p in "ABC"] == ["fast", "fast-coarse", "fast-coarse"]
    with pytest.raises(ConfigError, match="variant scope-curriculum is a variant of policy E, not D"):
        load_config("D", TRAINING_CONFIG, "scope-curriculum")
    with pytest.raises(ConfigError, match="no variant 'nope'; valid: paper, scope-curriculum"):
        load_config("E", TRAINING_CONFIG, "nope")
    # A variant of several policies applies to each with its own entry: D stays blind to force.
    d, e = load_config("D", TRAINING_CONFIG, "free-pool"), load_config("E", TRAINING_CONFIG, "free-pool")
    assert d.train_targets == e.train_targets == "A+F" and not d.force_obs and e.force_obs
    with pytest.raises(ConfigError, match="variant free-pool is a variant of policy D or E, not A"):
        load_config("A", TRAINING_CONFIG, "free-pool")


def test_a_mixed_run_samples_the_fem_wall_in_its_first_environments():
    # full_envs: the first environments step the full FEM stomach, the rest the run's fidelity, at one physics step
    cfg = load_config("E", TRAINING_CONFIG, "paper-step-full-mix")
    assert cfg.full_envs == 2 and cfg.fidelity == "fast-coarse" and cfg.vec_env == "subproc"
    envs = [make_env(cfg, rank)().unwrapped for rank in (0, 2)]
    assert [e.task.cfg.fidelity for e in envs] == ["full", "fast-coarse"]
    assert [e.task.sim.model.opt.timestep for e in envs] == [0.01, 0.01]
    full, fast = (e.task.sim.model for e in envs)
    assert fast.nflexnode == 8 and full.nflexnode == 0 and full.nv > 10 * fast.nv  # per-vertex FEM, not one cell
    assert cfg.task_config().fidelity == "fast-coarse"  # periodic evaluations and meta.json: the run's own wall
    with pytest.raises(ConfigError, match="full_envs .* needs the cpu backend"):
        load_config("E", TRAINING_CONFIG, "paper-step-full-mix", backend="warp")


def test_per_policy_ppo_and_task_blocks_merge_into_the_defaults(tmp_path):
    def edit(raw):
        raw["policies"]["E"]["ppo"] = {"n_epochs": 4}
        raw["policies"]["E"]["task"] = {"force_penalty": 0.5, "max_steps": 96}

    cfg = load_config("E", _yaml_with(tmp_path, edit))
    assert cfg.ppo.n_epochs == 4 and cfg.ppo.n_steps == 256 and cfg.ppo.net_arch == [256, 128, 64, 32]
    task = cfg.task_config()
    assert task.force_penalty == 0.5 and task.max_steps == 96 and task.env == "DE" and task.force_obs
    assert load_config("D", _yaml_with(tmp_path, edit)).ppo.n_epochs == 10  # other policies keep the defaults


def test_stray_files_in_the_checkpoint_folder_are_ignored(short_run, tmp_path):
    run, _ = short_run
    copy = tmp_path / "D" / run.name
    shutil.copytree(run, copy)
    (copy / "checkpoints" / "model_final.zip").write_bytes(b"a user's copy")
    assert latest_checkpoint(copy).name == "model_512.zip"


def test_training_says_where_it_writes_and_how_to_use_the_result(short_run, tmp_path):
    run, _ = short_run
    res = _cli("--policy", "D", "--out", str(run.parent.parent), "--config", str(run.parent.parent / "policies.yaml"),
               "--timesteps", "512")
    assert res.returncode == 0, res.stderr
    assert f"run folder: {run}" in res.stdout and "eval_sr=nan" not in res.stdout
    for hint in (f"--policy {run}", f"mjendo.evaluation --policies {run}", f"mjendo.artifacts ship {run} D"):
        assert hint in res.stdout


def test_same_seed_same_machine_trains_bit_identical_weights(short_run, tmp_path):
    # The reproducibility statement (docs/study.md): one machine, one seed, one set of versions.
    import torch
    from stable_baselines3 import PPO

    config = short_run[0].parent.parent / "policies.yaml"
    runs = [train("D", timesteps=256, out=tmp_path / name, config_file=config) for name in ("a", "b")]
    a, b = (PPO.load(str(r / "model.zip"), device="cpu").policy.state_dict() for r in runs)
    assert all(torch.equal(a[k], b[k]) for k in a)
    ea, eb = ((r / "episodes.csv").read_text() for r in runs)
    assert ea == eb


@pytest.mark.parametrize("variant,n,size,mean_range,spread,steps", [
    ("randomized-scope", 15, 22, (0.0, 160.0), 10.0, 20),   # insertion depth first, in mm
    ("short-horizon-timed", 15, 16, (0.0, 1.0), 0.1, 20),   # the share of the trial left
    ("guided-free-pool-critic", 15, 25, (0.0, 160.0), 10.0, 20),  # critic-only insertion depth, tip pose, time, phase
    ("paired", 11, 15, (0.0, 1.0), 0.5, 60),   # D's 11 inputs and E's contact indicator, which flips once it presses
    ("paper-step-history", 11, 75, (0.0, 1.0), 0.5, 60),  # the same, then four past observations of all 15
    ("anatomies-depth", 15, 20, (1.0, 100.0), 5.0, 20),   # the wall's distance along the tip axis, in mm
    ("anatomies-normal", 15, 18, (-1.0, 1.0), 0.05, 20),  # the target's surface normal, a unit vector
    ("anatomies-wide", 15, 18, (-1.0, 1.0), 0.05, 20),  # the same, every hidden layer twice as wide as well
])
def test_a_fine_tune_that_adds_inputs_starts_acting_and_valuing_as_its_source(monkeypatch, variant, n, size,
                                                                               mean_range, spread, steps):
    # Widening a policy: until training weighs the new inputs it must be the source, step for step in the real
    # simulator (random new weights would make it a different policy).
    import pickle

    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv

    from mjendo import train as train_module
    from mjendo import widen

    monkeypatch.setattr(widen, "STAT_STEPS", 256)
    cfg = load_config("E", TRAINING_CONFIG, variant, n_envs=2)
    model = train_module._start_from(cfg, DummyVecEnv([train_module.make_env(cfg, i) for i in range(2)]))
    src_dir = mjendo.paths.DATA / cfg.init_from
    source = PPO.load(str(src_dir / "model.zip"), device="cpu")
    with open(src_dir / "vecnormalize.pkl", "rb") as f:
        src_norm = pickle.load(f)
    norm = model.get_env()
    assert model.observation_space.shape == (size,) and source.observation_space.shape == (n,)
    first_mean, first_std = norm.obs_rms.mean[n], np.sqrt(norm.obs_rms.var[n])
    assert mean_range[0] < first_mean < mean_range[1] and first_std > spread / 10  # measured, not left at 0 / 1
    norm.training = False  # compare with the source's statistics as saved, not as training would move them
    obs, seen = norm.reset(), []
    for _ in range(steps):
        raw = norm.get_original_obs()
        own = np.clip((raw[:, :n] - src_norm.obs_rms.mean) / np.sqrt(src_norm.obs_rms.var + src_norm.epsilon),
                      -src_norm.clip_obs, src_norm.clip_obs).astype(np.float32)
        act, _ = model.predict(obs, deterministic=True)
        np.testing.assert_allclose(act, source.predict(own, deterministic=True)[0], atol=1e-4)
        with torch.no_grad():
            v_new = model.policy.predict_values(torch.as_tensor(obs, dtype=torch.float32))
            v_src = source.policy.predict_values(torch.as_tensor(own))
        np.testing.assert_allclose(v_new.numpy(), v_src.numpy(), rtol=1e-4, atol=1e-3)
        obs, *_ = norm.step(act)
        seen.append(raw[:, n])
    assert np.ptp(seen) > spread  # the new inputs changed while the actions stayed the source's
    d = load_config("D", TRAINING_CONFIG, init_from="models/policies/E")
    with pytest.raises(ConfigError, match="not drop or reorder them"):
        train_module._start_from(d, DummyVecEnv([train_module.make_env(d, 0)]))


def test_widen_scale_starts_the_new_inputs_at_the_old_ones_spread():
    # widen_scale 0 keeps the source (the test above); above 0 the new columns of each first layer are drawn at that
    # share of the layer's old spread, the old weights untouched, reproducibly from the seed, and the new policy acts
    # otherwise than its source on an observation whose new inputs are not zero.
    import torch

    from mjendo.widen import widen_state

    source = {"w": torch.randn(64, 11, generator=torch.Generator().manual_seed(1)), "b": torch.ones(64)}
    target = {"w": torch.zeros(64, 15), "b": torch.zeros(64)}
    zero, scaled = widen_state(source, target, 11), widen_state(source, target, 11, scale=0.5, seed=3)
    assert torch.equal(zero["w"][:, 11:], torch.zeros(64, 4)) and torch.equal(scaled["w"][:, :11], source["w"])
    assert float(scaled["w"][:, 11:].std()) == pytest.approx(0.5 * float(source["w"].std()), rel=0.2)
    assert torch.equal(scaled["w"], widen_state(source, target, 11, scale=0.5, seed=3)["w"])
    x = torch.ones(15)
    assert not torch.allclose(scaled["w"] @ x, zero["w"] @ x)
    with pytest.raises(ConfigError, match="widen_scale must be a number from 0"):
        load_config("E", TRAINING_CONFIG, widen_scale=-1.0)


def test_a_fine_tune_grows_the_hidden_layers_without_changing_the_policy_and_cannot_shrink_them():
    # ppo.net_arch wider than the source's: the new units start with zero outgoing weight, so the grown policy acts
    # and values as its source on the same inputs while its new units already respond; fewer units or another number
    # of layers is an error.
    import pickle

    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv

    from mjendo import train as train_module

    cfg = load_config("E", TRAINING_CONFIG, init_from="models/policies/E", n_envs=1)
    cfg.ppo.net_arch = [512, 256, 128, 64]
    model = train_module._start_from(cfg, DummyVecEnv([make_env(cfg, 0)]))
    source = PPO.load(str(mjendo.paths.DATA / "models/policies/E/model.zip"), device="cpu")
    assert [m.out_features for m in model.policy.mlp_extractor.policy_net if hasattr(m, "out_features")] == \
        [512, 256, 128, 64]
    with open(mjendo.paths.DATA / "models/policies/E/vecnormalize.pkl", "rb") as f:
        assert np.array_equal(model.get_env().obs_rms.mean, pickle.load(f).obs_rms.mean)  # the source's statistics
    obs = torch.randn(64, 15, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        for new, old in ((model.policy.get_distribution(obs).distribution.mean,
                          source.policy.get_distribution(obs).distribution.mean),
                         (model.policy.predict_values(obs), source.policy.predict_values(obs))):
            np.testing.assert_allclose(new.numpy(), old.numpy(), atol=1e-5)
        hidden = model.policy.mlp_extractor.policy_net[:2](obs)[:, 256:]
    assert float(hidden.abs().mean()) > 0.1  # the new units respond, with nothing downstream yet
    for fewer in ([256, 128, 64, 16], [256, 128, 64], [256, 128, 64, 32, 32]):
        cfg.ppo.net_arch = fewer
        with pytest.raises(ConfigError, match="not remove inputs or units, nor add or remove layers"):
            train_module._start_from(cfg, DummyVecEnv([make_env(cfg, 0)]))


def test_a_warmed_up_fine_tune_moves_the_critic_first_and_keeps_the_statistics(short_run, tmp_path):
    # critic_warmup_steps: the updates of the first steps train the value function alone; freeze_normalization: the
    # run keeps its start's observation statistics. After the warm-up the actor learns again.
    import pickle

    import torch
    import yaml
    from stable_baselines3 import PPO

    src, _ = short_run
    raw = yaml.safe_load((src.parent.parent / "policies.yaml").read_text())
    raw["defaults"].update(critic_warmup_steps=128, freeze_normalization=True)
    cfg_path = tmp_path / "policies.yaml"
    cfg_path.write_text(yaml.safe_dump(raw))

    def tune(steps, name):
        run = train("D", timesteps=steps, out=tmp_path, run_name=name, config_file=cfg_path, fidelity="fast",
                    init_from=src, learning_rate=1e-3, progress=False)
        return PPO.load(str(run / "model.zip"), device="cpu").policy.state_dict(), run

    before = PPO.load(str(src / "model.zip"), device="cpu").policy.state_dict()
    # Two updates of 128 samples: the first in the warm-up, the last at a learning rate of 0 (linear schedule).
    warm, run = tune(256, "warm")
    actor = [k for k in before if k.startswith(("mlp_extractor.policy_net.", "action_net.", "log_std"))]
    assert actor and all(torch.equal(before[k], warm[k]) for k in actor)
    assert any(not torch.equal(before[k], warm[k]) for k in before if k not in actor)
    with open(src / "vecnormalize.pkl", "rb") as f, open(run / "vecnormalize.pkl", "rb") as g:
        a, b = pickle.load(f).obs_rms, pickle.load(g).obs_rms
    assert np.array_equal(a.mean, b.mean) and np.array_equal(a.var, b.var) and a.count == b.count
    released, _ = tune(384, "released")  # the second update is past the warm-up
    assert any(not torch.equal(before[k], released[k]) for k in actor)
    with pytest.raises(ConfigError, match="critic_warmup_steps must be >= 0"):
        load_config("E", TRAINING_CONFIG, critic_warmup_steps=-1)


def test_weight_decay_pulls_the_weights_towards_zero(short_run, tmp_path):
    # ppo.weight_decay is Adam's coupled L2 penalty: the same fine-tune (seed, samples) with it ends with smaller
    # weight matrices than without, and its optimizer keeps it in every parameter group.
    import torch
    import yaml
    from stable_baselines3 import PPO

    src, _ = short_run
    raw = yaml.safe_load((src.parent.parent / "policies.yaml").read_text())
    norms = {}
    for decay in (0.0, 0.5):
        raw["defaults"]["ppo"]["weight_decay"] = decay
        cfg_path = tmp_path / f"policies-{decay}.yaml"
        cfg_path.write_text(yaml.safe_dump(raw))
        run = train("D", timesteps=256, out=tmp_path, run_name=f"decay-{decay}", config_file=cfg_path,
                    fidelity="fast", init_from=src, learning_rate=1e-3, progress=False)
        model = PPO.load(str(run / "model.zip"), device="cpu")
        assert {g["weight_decay"] for g in model.policy.optimizer.param_groups} == {decay}
        state = model.policy.state_dict()
        norms[decay] = sum(float(torch.norm(v)) for k, v in state.items() if v.ndim == 2)
    assert norms[0.5] < norms[0.0]
    raw["defaults"]["ppo"]["weight_decay"] = -1e-4
    cfg_path.write_text(yaml.safe_dump(raw))
    with pytest.raises(ConfigError, match="ent_coef and weight_decay >= 0"):
        load_config("D", cfg_path)


def test_a_fine_tune_adds_inputs_only_after_the_sources(monkeypatch):
    from mjendo import train as train_module

    cfg = load_config("E", TRAINING_CONFIG, "randomized-scope")
    cfg.task = {**cfg.task, "time_obs": True}  # wants the scope's state and the time left
    monkeypatch.setattr(artifacts, "obs_options",
                        lambda _d: {"force_obs": True, "scope_obs": False, "time_obs": True, "phase_obs": False,
                                    "step_obs": False, "depth_obs": False, "normal_obs": False, "plan_obs": False,
                                    "residual": False, "task_space": False, "history_obs": False})
    with pytest.raises(ConfigError, match="after the source's inputs, not drop or reorder them"):
        train_module._start_from(cfg, None)  # the scope's block would land before the source's time
    cfg.task = {**cfg.task, "time_obs": False}
    with pytest.raises(ConfigError, match="not drop or reorder"):
        train_module._start_from(cfg, None)  # the source's time left would be dropped
    cfg.task = {**cfg.task, "scope_obs": False, "time_obs": True, "phase_obs": True}
    monkeypatch.setattr(artifacts, "obs_options",
                        lambda _d: {"force_obs": True, "scope_obs": False, "time_obs": False, "phase_obs": True,
                                    "step_obs": False, "depth_obs": False, "normal_obs": False, "plan_obs": False,
                                    "residual": False, "task_space": False, "history_obs": False})
    with pytest.raises(ConfigError, match="breathing phase .* not drop or reorder"):
        train_module._start_from(cfg, None)  # the time left would land before the source's phase


def test_a_fine_tune_keeps_whether_actions_correct_the_baseline(monkeypatch):
    from mjendo import train as train_module

    cfg = load_config("E", TRAINING_CONFIG, "anatomies-residual")
    cfg.init_from = "models/policies/E"  # acts alone: its actions would mean something else under residual
    with pytest.raises(ConfigError, match="does not and this run corrects the baseline.*train from scratch"):
        train_module._start_from(cfg, None)
    cfg.task = {**cfg.task, "residual": False}
    monkeypatch.setattr(artifacts, "obs_options", lambda _d: {**{k: False for k in OBS_OPTIONS},
                                                              "force_obs": True, "residual": True})
    with pytest.raises(ConfigError, match="corrects the baseline controller's actions .* and this run does not"):
        train_module._start_from(cfg, None)
    cfg.task = {**cfg.task, "task_space": True}  # a tip displacement is no joint command either
    monkeypatch.setattr(artifacts, "obs_options", lambda _d: {**{k: False for k in OBS_OPTIONS}, "force_obs": True})
    with pytest.raises(ConfigError, match="does not and this run asks the controller for a tip displacement"):
        train_module._start_from(cfg, None)


def test_an_asymmetric_critic_values_inputs_the_policy_never_acts_on(short_run, tmp_path):
    import yaml
    from stable_baselines3 import PPO

    from mjendo.asymmetric import AsymmetricPolicy

    raw = yaml.safe_load((short_run[0].parent.parent / "policies.yaml").read_text())
    raw["variants"]["asym"] = {"policy": "D", "critic_only": ["scope_obs", "time_obs", "phase_obs"],
                               "task": {"scope_obs": True, "time_obs": True, "phase_obs": True}}
    (tmp_path / "policies.yaml").write_text(yaml.safe_dump(raw))
    run = train("D", timesteps=256, out=tmp_path, config_file=tmp_path / "policies.yaml", variant="asym")
    model = PPO.load(str(run / "model.zip"), device="cpu")
    assert isinstance(model.policy, AsymmetricPolicy) and model.policy.actor_inputs == 11
    ctrl = PPOController.from_folder(run)  # the evaluation's controller, built from meta.json like any policy
    env = EndoscopeEnv("DE", force_obs=False, scope_obs=True, time_obs=True, phase_obs=True)
    obs, _ = env.reset(seed=3)
    seen = [obs]
    for _ in range(15):  # insert and bend: the scope's state, the time and the phase all change
        obs, *_ = env.step(np.array([0.4, 0.0, 0.0, 0.0, 0.4]))
        seen.append(obs)
    seen = np.array(seen)
    swapped = seen.copy()
    swapped[:, 11:] = seen[::-1, 11:]  # the critic-only inputs of other states
    assert np.ptp(seen[:, 11:], axis=0).max() > 1.0
    np.testing.assert_array_equal(ctrl.act(seen, None), ctrl.act(swapped, None))
    import torch

    with torch.no_grad():
        values = [model.policy.predict_values(torch.as_tensor(ctrl.normalize(o))).numpy() for o in (seen, swapped)]
    assert np.abs(values[0] - values[1]).max() > 1e-3  # the critic does weigh them
    # A policy that already acts on those inputs cannot be continued with them hidden from it.
    raw["variants"]["seeing"] = {**raw["variants"]["asym"], "critic_only": []}
    (tmp_path / "policies.yaml").write_text(yaml.safe_dump(raw))
    seeing = train("D", timesteps=128, out=tmp_path, config_file=tmp_path / "policies.yaml", variant="seeing")
    with pytest.raises(ConfigError, match="already acts on"):
        train("D", timesteps=128, out=tmp_path / "x", config_file=tmp_path / "policies.yaml", variant="asym",
              init_from=seeing, fidelity="fast")


@pytest.mark.parametrize("task,critic_only,message", [
    ({"scope_obs": True}, ["force_obs"], "cannot be critic-only inputs"),
    ({}, ["scope_obs"], "which the task does not observe"),
    ({"scope_obs": True, "phase_obs": True}, ["scope_obs"], "must come after every block the policy sees"),
])
def test_critic_only_inputs_are_validated(tmp_path, task, critic_only, message):
    def edit(raw):
        raw["variants"]["bad"] = {"policy": "E", "task": task, "critic_only": critic_only}

    with pytest.raises(ConfigError, match=message):
        load_config("E", _yaml_with(tmp_path, edit), "bad")
