"""mjendo outside the checkout: a wheel installed into a fresh virtualenv runs policy E; imports stay light."""

import re
import subprocess
import sys
import sysconfig
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

EPISODE = textwrap.dedent("""
    import gymnasium as gym
    import mjendo
    from mjendo import paths
    from mjendo.policies import load_controller
    from mjendo.rollout import run

    assert not paths.IN_CHECKOUT and "site-packages" in str(paths.MODELS), paths.MODELS
    env = gym.make("mjendo/DE-v0", force_obs=True, max_steps=80).unwrapped
    ctrl = load_controller(str(paths.policies_dir() / "v0" / "E"), env.task)  # a shipped policy from the wheel
    assert gym.make("mjendo/DE-v1").unwrapped.task.targets.size >= 50  # the target map travels too
    info, ret = run(env, ctrl, seed=901)
    print("episode", info["step"], round(info["distance_mm"], 2), info["is_success"], mjendo.__file__)
""")


@pytest.mark.integration
def test_wheel_installs_into_a_fresh_venv_and_runs_policy_e(tmp_path):
    # Build from a copy of the sources: setuptools leaves a build/ folder in the tree it builds.
    import shutil

    src = tmp_path / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(ROOT / name, src / name)
    for name in ("mjendo", "models", "train"):
        shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__"))
    wheels = tmp_path / "wheels"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w",
                    str(wheels), str(src)], check=True, capture_output=True, cwd=tmp_path)
    (wheel,) = wheels.glob("mjendo-*.whl")
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    python = venv / "bin" / "python"
    subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "-q", str(wheel)],
                   check=True, capture_output=True)
    # The dependencies (MuJoCo, torch, SB3, ...) come from this environment's site-packages, appended after the
    # fresh venv's own: mjendo itself can only come from the wheel (this environment's editable mjendo is not
    # activated without its .pth file being processed).
    fresh_site = Path(subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                                     check=True, capture_output=True, text=True).stdout.strip())
    (fresh_site / "deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    res = subprocess.run([str(python), "-c", EPISODE], cwd=outside, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    line = [ln for ln in res.stdout.splitlines() if ln.startswith("episode")][-1]
    assert str(venv) in line and str(ROOT) not in line  # the installed copy ran
    steps = int(line.split()[1])
    assert 1 <= steps <= 80


@pytest.mark.parametrize("module", ["mjendo", "mjendo.units", "mjendo.config", "mjendo.anatomy"])
def test_importing_mjendo_registers_the_ids_without_loading_mujoco(module):
    code = f"import sys, {module}; print(sorted(m for m in ('mujoco', 'gymnasium') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "['gymnasium']"


def test_ids_are_registered_whichever_is_imported_first():
    versions = ("v0", "v1", "10ms-v2")
    ids = ["endogym-v0", *(f"mjendo/{e}-{v}" for e in ("DE", "FE", "SE", "UE1", "UE2") for v in versions)]
    for code in ("import mjendo, gymnasium as g", "import gymnasium as g, mjendo"):
        res = subprocess.run([sys.executable, "-c", code + "; print(sorted(i for i in g.registry if 'mjendo' in i "
                              "or i == 'endogym-v0'))"], capture_output=True, text=True, check=True)
        assert res.stdout.strip() == str(sorted(ids))


@pytest.mark.parametrize("args", [["mjendo.anatomy", "report"], ["mjendo.scene", "--help"], ["mjendo.train", "--help"],
                                  ["mjendo.evaluation", "--help"], ["mjendo.viewer", "--help"],
                                  ["mjendo.compare", "--help"]])
def test_command_line_tools_start_without_warnings(args):
    res = subprocess.run([sys.executable, "-W", "default", "-m", *args], capture_output=True, text=True, cwd=ROOT)
    assert res.returncode == 0 and "Warning" not in res.stderr, res.stderr


def test_the_tracked_tree_holds_code_models_and_results_not_runs():
    files = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, text=True, check=True)
    paths = [ROOT / f for f in files.stdout.split("\0") if f]
    if not paths:
        pytest.skip("not a git checkout")
    sizes = {p.relative_to(ROOT).as_posix(): p.stat().st_size for p in paths if p.exists()}
    assert not [p for p in sizes if p.startswith("runs/")]  # training runs stay out of git
    assert sum(sizes.values()) < 25e6
    big = [p for p, n in sizes.items() if n > 2e6 and not (p.startswith("docs/media/") and p.endswith(".mp4"))]
    assert not big, big


def test_readme_and_docs_describe_the_product_not_how_it_was_built():
    """History belongs in CHANGELOG.md: the README and docs/ say what is true now, in under 160 lines."""
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    worklog = re.compile(r"\b(sessions?|rounds?)\b", re.IGNORECASE)
    found = [f"{p.name}:{i}" for p in pages for i, line in enumerate(p.read_text().splitlines(), 1)
             if worklog.search(line)]
    assert not found, found
    assert len((ROOT / "README.md").read_text().splitlines()) < 160
