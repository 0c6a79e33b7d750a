"""Policy folders: every shipped policy loads and acts, normalisation matches SB3, bad files are named."""

import json
import pickle
import shutil
import warnings

import numpy as np
import pytest
from scipy.stats import binom

from mjendo import artifacts
from mjendo.config import PAPER_ACTION_LIMIT, PAPER_EVAL_STEPS, ConfigError
from mjendo.envs import EndoscopeEnv
from mjendo.paths import TRAINING_CONFIG, policies_dir
from mjendo.policies import PolicyError, PPOController, force_obs_of, load_controller
from mjendo.rollout import run
from mjendo.train_config import shipped_variant

TRAINED_IN = {"A": "FE", "B": "SE", "C": "SE", "D": "DE", "E": "DE"}  # paper: the five policies
V0 = policies_dir() / "v0"  # the task-version-0 policies: always shipped, so these tests always run
E0 = V0 / "E"
E1 = policies_dir() / "E"  # the current version's shipped E, its value function kept
# Every shipped policy folder: version 0's five, and the current version's as far as they are shipped.
SHIPPED = [(0, V0 / p, p) for p in TRAINED_IN] + [(1, policies_dir() / p, p) for p in TRAINED_IN
                                                   if (policies_dir() / p / artifacts.MODEL_FILE).exists()]
# Shipped variants (models/policies/variants/<P>-<variant>/) are held to the same test.
SHIPPED += [(1, f, artifacts.read_meta(f)["policy"]) for f in sorted((policies_dir() / "variants").glob("*"))
            if (f / artifacts.MODEL_FILE).exists()]


@pytest.mark.parametrize("version,folder,policy", SHIPPED,
                         ids=[f"v{v}-{p}" if f.parent.name != "variants" else f"v{v}-{f.name}" for v, f, p in SHIPPED])
def test_every_shipped_policy_loads_and_reaches_a_target_in_its_environment(version, folder, policy):
    meta = artifacts.read_meta(folder)
    assert meta["task"]["env"] == TRAINED_IN[policy] and meta["timesteps"] > 100_000
    assert meta["mjendo_version"] and meta["scene_fingerprint"] and meta["commit"]  # provenance
    # the command as a user types it: no interpreter path, no Ray worker's argv
    assert meta["command"].startswith(("python -m mjendo.", "make ")) and "/work" not in meta["command"]
    env = EndoscopeEnv(TRAINED_IN[policy], force_obs=force_obs_of(str(folder)), max_steps=PAPER_EVAL_STEPS,
                       version=version)
    ctrl = load_controller(str(folder), env.task)
    assert ctrl.n_obs == (15 if policy in "CE" else 11)
    # On six trials it never used, a policy must succeed as often as its own validation rate (the study's,
    # published with its seed; else the run's last periodic evaluation, recorded at shipping; 90 % where
    # neither is) makes in all but 2 % of six-trial draws, at least once, and must bring the tip to half its
    # starting distance on average.
    p = _validation_rate(folder)
    least = max(1, int(binom.ppf(0.02, 6, p)))
    outcomes, start, final = [], [], []
    for seed in range(900, 906):  # seeds the evaluation study never uses
        env.reset(seed=seed)
        start.append(env.task.distance_mm())
        info, _ = run(env, ctrl, seed=seed)
        outcomes.append(info["is_success"])
        final.append(info["distance_mm"])
        if info["is_success"]:
            assert info["distance_mm"] < 3.0 and info["step"] <= PAPER_EVAL_STEPS
    assert sum(outcomes) >= least, f"policy {policy} reached {sum(outcomes)} of 6 targets (validation rate {p:.2f})"
    assert np.mean(final) < 0.5 * np.mean(start), (start, final)


def _validation_rate(folder) -> float:
    meta = artifacts.read_meta(folder)
    path = folder / "seeds" / f"seed{meta.get('seed')}" / "study_validation.json"
    if path.exists():
        return json.loads(path.read_text())["success_rate"]
    return meta.get("final_evaluation", {}).get("success_rate", 0.9)


def test_normalize_is_sb3s_vecnormalize():
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    ctrl = PPOController.from_folder(E0)
    vn = VecNormalize.load(str(E0 / artifacts.NORM_FILE), DummyVecEnv([lambda: EndoscopeEnv("DE", version=0)]))
    env = EndoscopeEnv("DE", version=0)
    obs, _ = env.reset(seed=1)
    for _ in range(5):
        np.testing.assert_allclose(ctrl.normalize(obs), vn.normalize_obs(obs), rtol=1e-6, atol=1e-6)
        obs, *_ = env.step(np.full(5, 0.3))
    big = np.full(15, 1e6, np.float32)  # clipped at clip_obs
    np.testing.assert_allclose(ctrl.normalize(big), vn.normalize_obs(big), rtol=1e-6)


def test_act_is_sb3s_deterministic_predict():
    """The lean actor pass the evaluation uses returns predict's action: the mean, clipped to the box."""
    ctrl = PPOController.from_folder(policies_dir() / "E")
    rng = np.random.default_rng(3)
    clipped = 0
    for scale in (1.0, 30.0, 300.0):  # large observations drive the mean past the box: the clip must match too
        for _ in range(20):
            obs = (rng.normal(size=ctrl.n_obs) * scale).astype(np.float32)
            want, _ = ctrl.model.predict(ctrl.normalize(obs), deterministic=True)
            got = ctrl.act(obs, None)
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)
            clipped += int(np.any(np.abs(want) >= PAPER_ACTION_LIMIT))
    assert clipped > 0
    batch = (rng.normal(size=(16, ctrl.n_obs)) * 30.0).astype(np.float32)  # the batched backend's call
    np.testing.assert_allclose(ctrl.act(batch, None), ctrl.model.predict(ctrl.normalize(batch), deterministic=True)[0],
                               rtol=0, atol=1e-6)


def test_what_a_policy_observes_comes_from_its_own_folder(tmp_path, monkeypatch):
    # No training YAML is read: a policy folder alone says whether it wants contact and force.
    monkeypatch.setattr("mjendo.paths.TRAINING_CONFIG", tmp_path / "missing.yaml")
    assert force_obs_of(str(V0 / "E")) and force_obs_of(str(V0 / "C")) and not force_obs_of(str(V0 / "D"))
    copy = tmp_path / "E_copy"
    shutil.copytree(E0, copy)
    assert force_obs_of(str(copy)) and force_obs_of(str(copy / "model.zip"))


def test_a_published_variant_is_named_by_its_folder(monkeypatch, tmp_path):
    # The FEM stomach's E is published as a variant: its name alone must reach it, from any working directory.
    monkeypatch.chdir(tmp_path)
    assert artifacts.resolve("E-paper-step") == policies_dir() / "variants" / "E-paper-step"
    ctrl = load_controller("E-paper-step")
    assert ctrl.n_obs == 15 and force_obs_of("E-paper-step") and not force_obs_of("D-paper-step")
    with pytest.raises(ConfigError, match=r"unknown policy 'E-nothing'.*a published variant \(.*E-paper-step"):
        artifacts.resolve("E-nothing")


@pytest.fixture
def policy_copy(tmp_path):
    d = tmp_path / "E"
    d.mkdir()
    for name in ("model.zip", "vecnormalize.pkl", "meta.json"):
        shutil.copy2(E0 / name, d / name)
    return d


def test_normalisation_file_that_is_not_a_vecnormalize(policy_copy):
    (policy_copy / "vecnormalize.pkl").write_bytes(pickle.dumps({"obs_rms": None}))
    with pytest.raises(PolicyError, match=r"vecnormalize.pkl holds a dict, not a Stable-Baselines3 VecNormalize"):
        artifacts.load(policy_copy)


def test_normalisation_file_of_another_policy(policy_copy):
    shutil.copy2(V0 / "B" / "vecnormalize.pkl", policy_copy / "vecnormalize.pkl")
    with pytest.raises(PolicyError, match=r"normalises 11 observations but .*model.zip takes 15.*different runs"):
        artifacts.load(policy_copy)


@pytest.mark.parametrize("content,message", [
    ("[1, 2]", "must hold a JSON object"),
    ("{not json", r"cannot read .*meta.json"),
    ('{"task": {"env": "XX"}}', "its task is not valid"),
    ('{"observation": [{"name": "x", "size": 11, "unit": "mm"}]}', "describes 11 observations but"),
])
def test_broken_meta_json_is_named(policy_copy, content, message):
    (policy_copy / "meta.json").write_text(content)
    with pytest.raises(PolicyError, match=message):
        artifacts.load(policy_copy)


def test_corrupt_normalisation_file(policy_copy):
    (policy_copy / "vecnormalize.pkl").write_bytes(b"\x80\x04truncated")
    with pytest.raises(PolicyError, match="vecnormalize.pkl.*corrupt"):
        artifacts.load(policy_copy)


def test_ship_copies_what_the_run_recorded(tmp_path, monkeypatch, policy_copy):
    monkeypatch.setenv("MJENDO_POLICIES", str(tmp_path / "shipped"))
    meta = json.loads((policy_copy / "meta.json").read_text())
    meta["task"]["cable_mm_per_unit"] = 2.0  # a run made with other scales keeps them when shipped
    (policy_copy / "meta.json").write_text(json.dumps(meta))
    dest = artifacts.ship(policy_copy, "E")
    assert json.loads((dest / "meta.json").read_text())["task"]["cable_mm_per_unit"] == 2.0
    # Model, normalisation, meta and config only; the model without the optimizer's moments, and it loads.
    assert {p.name for p in dest.iterdir()} <= {"config.yaml", "meta.json", "model.zip", "vecnormalize.pkl"}
    assert artifacts.load(dest).model.policy is not None
    # A variant's run ships beside the letter's shipped recipe, never over it; that recipe's runs ship as the letter,
    # and a run of the paper's entry of a letter that ships another recipe goes beside it as <P>-paper.
    meta["training"]["variant"] = "free-pool"
    (policy_copy / "meta.json").write_text(json.dumps(meta))
    assert artifacts.ship(policy_copy, "E") == tmp_path / "shipped" / "variants" / "E-free-pool"
    meta["training"]["variant"] = shipped_variant("E", TRAINING_CONFIG)
    (policy_copy / "meta.json").write_text(json.dumps(meta))
    assert artifacts.ship(policy_copy, "E") == tmp_path / "shipped" / "E"
    meta["training"]["variant"] = None
    (policy_copy / "meta.json").write_text(json.dumps(meta))
    assert artifacts.home("E", None) == tmp_path / "shipped" / "variants" / "E-paper"
    assert artifacts.home("A", None) == tmp_path / "shipped" / "A"
    # `ship --actor-only`: an evaluation copy (as the variants that only act are published) of a run that has a
    # value function; without the flag the copy keeps it
    run = tmp_path / "run"
    run.mkdir()
    for name in ("model.zip", "vecnormalize.pkl", "meta.json"):
        shutil.copy2(E1 / name, run / name)
    for flag, actor_only in (([], False), (["--actor-only"], True)):
        assert artifacts.main(["ship", str(run), "E", *flag]) == 0
        assert artifacts.is_actor_only(tmp_path / "shipped" / "E" / "model.zip") == actor_only
    meta["timesteps"] = 0
    (policy_copy / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(PolicyError, match="not a finished run"):
        artifacts.ship(policy_copy, "E")


def test_an_evaluation_copy_acts_as_its_policy_in_half_the_bytes(tmp_path):
    """A study seed that is only evaluated ships without its value function (as do task version 0's policies):
    same actions, smaller file, and no fine-tune can start from it by mistake."""
    from mjendo.config import ConfigError
    from mjendo.train import train

    source, dest = policies_dir() / "E", tmp_path / "copy"
    dest.mkdir()
    shutil.copy2(source / "vecnormalize.pkl", dest)
    shutil.copy2(source / "meta.json", dest)
    artifacts.slim_copy(source / "model.zip", dest / "model.zip", actor_only=True)
    assert artifacts.is_actor_only(dest / "model.zip") and not artifacts.is_actor_only(source / "model.zip")
    assert artifacts.is_actor_only(E0 / "model.zip")
    assert (dest / "model.zip").stat().st_size < 0.6 * (source / "model.zip").stat().st_size
    env = EndoscopeEnv("DE", force_obs=True, max_steps=PAPER_EVAL_STEPS)
    full, copy = load_controller(str(source), env.task), load_controller(str(dest), env.task)
    obs = np.random.default_rng(0).normal(0.0, 30.0, (64, full.n_obs)).astype(np.float32)
    assert np.array_equal(full.act(obs, env.task), copy.act(obs, env.task))
    with pytest.raises(ConfigError, match="evaluation copy"):
        train("E", timesteps=256, out=tmp_path / "runs", init_from=dest, progress=False, variant="paper",
              fidelity="fast")


def test_a_policy_trained_in_other_scenes_warns_naming_both(policy_copy):
    meta = json.loads((policy_copy / "meta.json").read_text())
    now = meta["scene_fingerprint"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        artifacts.load(policy_copy)  # the scenes it was trained in: no warning
    meta["scene_fingerprint"] = "0123456789ab"
    (policy_copy / "meta.json").write_text(json.dumps(meta))
    with pytest.warns(RuntimeWarning, match=f"trained on scenes 0123456789ab, the installed scenes are {now}"):
        artifacts.load(policy_copy)


def test_a_policy_trained_on_other_target_lists_warns_naming_both(policy_copy):
    from mjendo import targets

    meta = json.loads((policy_copy / "meta.json").read_text())
    version = int(artifacts.trained_task(meta)["version"])
    meta["targets_fingerprint"] = "ba9876543210"
    (policy_copy / "meta.json").write_text(json.dumps(meta))
    with pytest.warns(RuntimeWarning, match=f"trained on target lists ba9876543210, the installed target lists are "
                                            f"{targets.fingerprint(version)}: the targets were drawn again"):
        artifacts.load(policy_copy)


def test_compare_tells_a_reproduced_policy_from_a_changed_one(tmp_path):
    """`python -m mjendo.artifacts compare`: a retrained seed that matches its published folder bit for bit, and what
    it names when one weight or one normalisation statistic differs."""
    source = policies_dir() / "E"
    copy, slim = tmp_path / "copy", tmp_path / "slim"
    shutil.copytree(source, copy, ignore=shutil.ignore_patterns("seeds"))
    slim.mkdir()
    for name in ("vecnormalize.pkl", "meta.json"):
        shutil.copy2(source / name, slim / name)
    artifacts.slim_copy(source / "model.zip", slim / "model.zip", actor_only=True)
    assert artifacts.comparison(source, copy) == dict.fromkeys(
        ("task", "actor weights", "value function", "normalisation"), True)
    assert artifacts.main(["compare", str(source), str(copy)]) == 0
    # An evaluation copy has no value function to compare: the rest still matches, also when its meta was written
    # before a task option existed (it records no value: the default); a changed task option is a difference.
    meta = json.loads((slim / "meta.json").read_text())
    older = {**meta, "task": {k: v for k, v in meta["task"].items() if k not in ("time_obs", "success_mm")}}
    (slim / "meta.json").write_text(json.dumps(older))
    assert artifacts.comparison(copy, slim) == dict.fromkeys(("task", "actor weights", "normalisation"), True)
    (slim / "meta.json").write_text(json.dumps({**meta, "task": {**meta["task"], "success_mm": 2.0}}))
    assert not artifacts.comparison(copy, slim)["task"]
    (slim / "meta.json").write_text(json.dumps(meta))
    from stable_baselines3 import PPO

    model = PPO.load(str(copy / "model.zip"), device="cpu")
    with __import__("torch").no_grad():
        model.policy.action_net.bias[0] += 1e-6
    model.save(str(copy / "model.zip"))
    vn = pickle.loads((copy / "vecnormalize.pkl").read_bytes())
    vn.obs_rms.var[3] *= 1.0 + 1e-9
    vn.venv, vn.class_attributes, vn.returns = None, {}, None  # what VecNormalize holds back when pickled
    (copy / "vecnormalize.pkl").write_bytes(pickle.dumps(vn))
    parts = artifacts.comparison(source, copy)
    assert not parts["actor weights"] and not parts["normalisation"] and parts["value function"] and parts["task"]
    assert artifacts.main(["compare", str(source), str(copy)]) == 1
    assert artifacts.main(["compare", str(source), str(tmp_path / "missing")]) == 2  # the one-line error


def test_input_weights_name_each_block_and_show_the_widened_force_inputs():
    # The shipped E is D widened to the force inputs at zero weight: its force columns stay small next to the paper
    # observation's; C, trained with the force from its first step, weights them as the rest.
    shipped = {name: (lo, hi) for name, lo, hi in artifacts.input_weights("E")}
    assert list(shipped) == ["ee_to_target", "ee_velocity", "cable_lengths", "previous_axial_action", "contact",
                             "force"]
    assert shipped["force"][1] < 0.5 < 1.0 < shipped["ee_to_target"][0]
    c = {name: (lo, hi) for name, lo, hi in artifacts.input_weights("C")}
    assert c["force"][0] > 1.0
    assert artifacts.main(["inputs", "nosuch"]) == 2
