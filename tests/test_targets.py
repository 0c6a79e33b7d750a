"""The reachability map and the target lists: classes follow the rule, and free space really misses them."""

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import minimize

from mjendo import targets
from mjendo.config import CURRENT_VERSION, VERSIONS, fidelity_preset
from mjendo.sim import Simulator
from mjendo.task import NavigationTask, free_targets

MAP_VERSIONS = sorted(v for v in VERSIONS if v >= 1)  # each task version from 1 has its own map
MAPS = {v: targets.read_map(targets.targets_file(v)) for v in MAP_VERSIONS}
TABLES = {v: targets.load(v) for v in MAP_VERSIONS}
POINTS_OF = {v: {p["id"]: p for p in MAPS[v]["points"]} for v in MAP_VERSIONS}
MAP, POINTS = TABLES[CURRENT_VERSION], POINTS_OF[CURRENT_VERSION]


@pytest.mark.parametrize("version", MAP_VERSIONS)
def test_classes_follow_the_rule_and_lists_are_drawn_from_them(version):
    def near(x, edge):  # the file keeps two decimals: a value rounded onto a boundary may be either side
        return abs(x - edge) <= 0.005

    table, points = TABLES[version], POINTS_OF[version]
    # measured at the version's own physics step (version 1's map predates the field: 20 ms, its step)
    assert MAPS[version]["info"].get("physics_step_s", 0.02) == fidelity_preset("fast", version).timestep_s
    for p in points.values():
        free, wall, phase = p["free_mm"], p["wall_mm"], p["phase_mm"]
        if near(free, 3) or near(free, 10) or near(wall, 3) or near(phase, 3):
            continue
        expected = ("free" if free < 3 else "between" if free < 10 else
                    "contact_aided" if wall < 3 and phase < 3 else "out_of_reach")
        assert p["class"] == expected, p
        assert (p["demos"] is not None) == (p["class"] == "contact_aided"), p
    a, b, f = (set(table.lists[k]) for k in "ABF")
    assert not (a & b) and len(b) >= 50 and len(a) >= len(b)
    assert all(points[i]["class"] in ("free", "contact_aided") for i in a | b)
    assert all(points[i]["class"] == "free" for i in f)
    for name in "AB":  # at least 60 % of each list needs the wall (free-space distance >= 10 mm)
        share = np.mean([points[i]["free_mm"] >= 10 for i in table.lists[name]])
        assert share >= 0.6, (name, share)


def replay(name: str, point: int, run: int, version: int = CURRENT_VERSION) -> float:
    """Closest approach (mm) of the demonstrator the map recorded for ``point`` in ``run`` (0: SE, k: DE phase k)."""
    env = "SE" if run == 0 else "DE"
    task = NavigationTask(env=env, target_list=name, max_steps=targets.TRIAL_STEPS, randomize_phase=False,
                          version=version)
    phase = None if run == 0 else (run - 1) * len(task.start_states) // targets.PHASES
    task.reset(np.random.default_rng(0), phase)
    task.set_target(point)
    demo = targets.DEMOS[POINTS_OF[version][point]["demos"][run]]
    closest = np.inf
    for k in range(targets.TRIAL_STEPS):
        res = task.step(targets.demo_action(demo, k))
        closest = min(closest, res.info["distance_mm"])
        if res.terminated or res.truncated:
            break
    return closest


def aided(name: str, version: int = CURRENT_VERSION) -> list[int]:
    return [i for i in TABLES[version].lists[name] if POINTS_OF[version][i]["class"] == "contact_aided"]


@pytest.mark.parametrize("version", MAP_VERSIONS)
@pytest.mark.parametrize("name", ["A", "B"])
def test_listed_contact_aided_targets_are_reached_in_a_trial_by_their_recorded_demonstrators(name, version):
    # The map's promise, replayed through the task itself: a sample of each list's contact-aided targets, in SE
    # and from one load phase of DE (every target and phase: the slow tier).
    for j, point in enumerate(aided(name, version)[::12]):
        for run in (0, 1 + j % targets.PHASES):
            assert replay(name, point, run, version) < 3.0, (name, point, run)


@pytest.mark.slow
@pytest.mark.parametrize("version", MAP_VERSIONS)
@pytest.mark.parametrize("name", ["A", "B"])
def test_every_listed_contact_aided_target_is_reached_from_every_start(name, version):
    misses = [(p, r) for p in aided(name, version) for r in range(1 + targets.PHASES)
              if replay(name, p, r, version) >= 3.0]
    assert not misses


def test_listed_targets_are_on_the_lumen_and_move_with_the_wall():
    task = NavigationTask(env="DE", randomize_phase=False)
    start = task.list_positions()
    task.sim.set_controls(np.zeros(4), task.sim.insertion_range[0])
    moved = np.zeros(len(start))
    for _ in range(8):  # one 4 s load cycle, both of its switches
        task.sim.step(int(round(0.5 / task.sim.model.opt.timestep)))
        moved = np.maximum(moved, np.linalg.norm(task.list_positions() - start, axis=1) * 1e3)
    assert np.median(moved) > 2.0  # measured: 3.4 mm between the two load states
    st = task.stomach
    assert st.mesh.inner[task.target_tri].all() and np.allclose(task.target_bary.sum(1), 1.0)


class FreeSpace:
    """The tip's settled position in free space for (insertion, bending direction, bending magnitude)."""

    def __init__(self, version: int = CURRENT_VERSION):
        self.sim = Simulator("FE", version=version)
        self.pull_max = float(self.sim.cable_pull_max[0])
        self.steps = int(round(0.5 / self.sim.model.opt.timestep))

    def tip(self, x: np.ndarray) -> np.ndarray:
        ins = float(np.clip(x[0], 0.0, self.sim.insertion_range[1]))
        mag = float(np.clip(x[2], 0.0, 1.0)) * self.pull_max
        self.sim.reset()
        self.sim.set_controls(targets._pulls(x[1], mag), ins)
        self.sim.step(self.steps)
        return self.sim.tip_pos()


@pytest.mark.parametrize("version", MAP_VERSIONS)
@pytest.mark.parametrize("name", ["A", "B"])
def test_contact_aided_targets_are_out_of_free_space_reach_by_an_independent_search(name, version):
    # Not the map's sweep: a coarse grid then Nelder-Mead over insertion, direction and magnitude, settling
    # from straight for every pose. It must not bring the tip within 10 mm of any contact-aided target
    # (a 1 mm allowance for the two searches' different paths into the same pose).
    space = FreeSpace(version)
    rest = free_targets("fast", version)
    points = POINTS_OF[version]
    listed = aided(name, version)
    pts = TABLES[version].positions(rest, listed)
    grid = [np.array([q, d, m]) for q in np.linspace(0, 0.16, 5) for d in np.linspace(0, 2 * np.pi, 8,
                                                                                         endpoint=False)
            for m in (0.0, 0.5, 1.0)]
    tips = np.array([space.tip(x) for x in grid])
    for i, p in zip(listed, pts, strict=True):
        x0 = grid[int(np.argmin(np.linalg.norm(tips - p, axis=1)))]
        res = minimize(lambda x, p=p: np.linalg.norm(space.tip(x) - p), x0, method="Nelder-Mead",
                       options={"maxfev": 40, "initial_simplex": np.vstack([x0, x0 + np.diag([0.01, 0.4, 0.2])])})
        assert res.fun * 1e3 >= 9.0, (i, res.fun * 1e3, points[i]["free_mm"])


def test_a_missing_target_table_says_how_to_make_it(tmp_path):
    from mjendo.config import ConfigError

    with pytest.raises(ConfigError, match=r"targets.json is missing; measure the map first with "
                                          r"`python -m mjendo.targets map`"):
        targets.load(CURRENT_VERSION, tmp_path / "targets.json")
    assert targets.load(0, tmp_path / "targets.json").lists["A"]  # version 0's vertex targets need no table


def map_with_list_a(tmp_path, n: int) -> Path:
    """The committed map with list A cut to its first ``n`` contact-aided targets: replays that stay short."""
    meta = targets.read_map(targets.TARGETS_FILE)
    meta["lists"]["A"] = aided("A")[:n]
    path = tmp_path / "targets.json"
    path.write_text(json.dumps(meta))
    return path


def test_slack_replays_each_demonstrator_to_its_first_arrival(tmp_path):
    # Two of list A's contact-aided targets: each recorded demonstrator arrives within the trial, in SE and from
    # every load phase, and none sooner than 30 steps (75 mm of full-speed insertion): they lie deep.
    path = map_with_list_a(tmp_path, 2)
    steps = targets.arrival_steps("A", path)
    assert list(steps) == aided("A")[:2]
    for point, per_run in steps.items():
        assert len(per_run) == 1 + targets.PHASES and None not in per_run, (point, per_run)
        assert 30 <= min(per_run) and max(per_run) <= targets.TRIAL_STEPS, (point, per_run)


def test_slack_report_compares_the_full_stomach_trial_by_trial_even_when_nothing_arrives(monkeypatch):
    # The full stomach may bring no motion in within the trial: the report must say so, not fail on an empty median.
    fast = {1: [60, 61, 62, 63, 64], 2: [70, 71, 72, 73, 74]}
    full = {1: [None, 63, None, 65, 64], 2: [None] * 5}
    monkeypatch.setattr(targets, "arrival_steps", lambda name, fidelity="fast", **_: full if fidelity == "full"
                        else fast)
    report = targets._slack_report("A", "full")
    assert "by step 80 at 0" in report and "10 trials that arrive in the fast stomach: 3 arrive" in report
    assert "+2 steps later" in report  # median of (63-61, 65-63, 64-64) = median(2, 2, 0)
    monkeypatch.setattr(targets, "arrival_steps", lambda name, fidelity="fast", **_: {1: [None] * 5}
                        if fidelity == "full" else {1: fast[1]})
    assert targets._slack_report("A", "full").endswith("5 trials that arrive in the fast stomach: 0 arrive within "
                                                       "the trial in the full one")


def test_the_fastest_known_way_is_never_later_than_the_recorded_one_and_more_phases_include_the_maps_own(tmp_path):
    # One contact-aided target, its recorded demonstrators (one per start) raced against each other from every
    # start: from each start the fastest arrives no later than that start's own recorded one, and the recorded
    # one alone (SE's, replayed from SE) gives exactly its own arrival. Raced from 8 DE phases: SE and every other
    # phase are the map's 4 starts, so the fastest arrivals there equal the 4-phase race's; the phases between
    # them are new starts, each measured. (One test: both races share the 4-phase one, the costly part.)
    path = map_with_list_a(tmp_path, 1)
    (point, recorded), = targets.arrival_steps("A", path).items()
    demos = targets.recorded_demos("A", path)
    assert demos == sorted(set(POINTS[point]["demos"])) and point == aided("A")[0]
    (_, four), = targets.fastest_arrivals("A", path, demos=demos).items()
    assert len(four) == 1 + targets.PHASES and None not in four
    assert all(f <= r for f, r in zip(four, recorded, strict=True)), (four, recorded)
    se_only = targets.fastest_arrivals("A", path, demos=[POINTS[point]["demos"][0]])
    assert se_only[point][0] == recorded[0]
    (_, eight), = targets.fastest_arrivals("A", path, demos=demos, phases=8).items()
    assert len(eight) == 1 + 8 and eight[0] == four[0] and eight[1::2] == four[1:], (four, eight)
    assert all(s is None or 30 <= s <= targets.TRIAL_STEPS for s in eight[2::2]), eight


def test_the_known_way_ceiling_counts_free_targets_and_each_start_a_raced_demonstrator_reaches(tmp_path, capsys):
    # List A cut to one free and one contact-aided target, raced from DE's phase 0 alone: the map's own start,
    # from which the map found the contact-aided target reached, so the ceiling is the whole list. A set of
    # stomachs without --ceiling, and --per-anatomy without it, are refused with what to add.
    meta = targets.read_map(targets.TARGETS_FILE)
    free = next(i for i in meta["lists"]["A"] if POINTS[i]["class"] == "free")
    meta["lists"]["A"] = [free, aided("A")[0]]
    path = tmp_path / "targets.json"
    path.write_text(json.dumps(meta))
    c = targets.known_way_ceiling("A", phases=1, path=path)
    assert (c["targets"], c["free"], c["contact_aided"], c["missed_somewhere"]) == (2, 1, 1, 0), c
    assert c["pairs_reached"] == 1.0 and c["ceiling"] == 1.0 and 30 <= c["median_latest"] <= targets.TRIAL_STEPS
    assert targets.main(["slack", "--anatomy", "test"]) == 2
    assert "is a set of stomachs: add --ceiling" in capsys.readouterr().err
    assert targets.main(["slack", "--per-anatomy", str(path)]) == 2
    assert "--per-anatomy goes with --ceiling" in capsys.readouterr().err


def test_ceilings_set_each_stomachs_success_beside_its_ceiling_and_latest_arrival(monkeypatch, tmp_path, capsys):
    # Three stomachs whose known ways arrive later and later, and a policy that succeeds less the later they
    # do: the report lines them up per stomach and gives the correlations across stomachs.
    fake = {1: (1.0, 58.0), 2: (0.98, 63.0), 3: (0.95, 68.0)}
    monkeypatch.setattr(targets, "known_way_ceiling", lambda name, a, phases, env: {
        "targets": 30, "contact_aided": 20, "pairs_reached": fake[a][0], "missed_somewhere": 0,
        "median_latest": fake[a][1], "ceiling": fake[a][0]})
    csv = tmp_path / "per_anatomy.csv"
    csv.write_text("policy,env,anatomy,trials,success_pct\nE,DE,1,20,90.0\nE,DE,2,20,80.0\nE,DE,3,20,60.0\n"
                   "E,UE2,1,20,10.0\n")
    targets.print_ceilings("A", [1, 2, 3], 8, "DE", csv)
    out = capsys.readouterr().out.splitlines()
    assert out[1] == "  1: 30 (20), 100.0%, 0, step 58, 100.0%, 90.0 %"
    assert out[3].startswith("  3: 30 (20), 95.0%") and out[3].endswith("step 68, 95.0%, 60.0 %")
    ceiling, latest = (float(part.split(" ")[-1]) for part in out[-1].split(", "))
    assert ceiling > 0.9 and latest < -0.9 and out[-1].startswith("  E: correlation of success across 3 stomachs")


def test_success_by_slack_weighs_each_target_by_its_trials(tmp_path):
    # Success is pooled over the trials of the targets in each bin of latest arrival; targets outside the list
    # are ignored, and a file about other targets is refused with what to give instead.
    from mjendo.config import ConfigError

    csv = tmp_path / "per_target.csv"
    csv.write_text("policy,env,target,class,trials,success_pct\n"
                   "E,DE,1,contact_aided,4,100.0\nE,DE,2,contact_aided,12,50.0\nE,DE,3,contact_aided,4,0.0\n"
                   "E,DE,99,free,8,0.0\n")
    report = targets.success_by_slack({1: 55, 2: 58, 3: 79}, csv)
    assert report.splitlines()[1] == "  E, DE: 62.5 % (2), - (0), - (0), 0.0 % (1)"  # (4 + 6) of 16 trials
    with pytest.raises(ConfigError, match="holds none of this list's contact-aided targets"):
        targets.success_by_slack({7: 60}, csv)


def test_slack_refuses_what_it_cannot_measure_before_replaying_anything(tmp_path, capsys):
    # Both refusals come before any simulation: one line naming the problem and the fix, exit status 2.
    assert targets.main(["slack", "--fastest", "--fidelity", "full"]) == 2
    assert "hours in the FEM stomach: give a fast --fidelity" in capsys.readouterr().err
    assert targets.main(["slack", "--timestep", "0.01"]) == 2
    assert "--timestep goes with --fastest" in capsys.readouterr().err
    assert targets.main(["slack", "--per-target", str(tmp_path / "missing.csv")]) == 2
    assert "missing.csv does not exist: give the per_target.csv a study wrote" in capsys.readouterr().err
    for args in (["--phases", "8"], ["--env", "UE2"], ["--recorded-demos"]):
        assert targets.main(["slack", *args]) == 2
        assert "add --fastest to race demonstrators from other phases" in capsys.readouterr().err
    assert targets.main(["slack", "--fastest", "--phases", "0"]) == 2
    assert "--phases 0: give 1 to" in capsys.readouterr().err
    assert targets.main(["map", "--episodes", "0"]) == 2  # was a NumPy error from deep in the exploration
    assert "--episodes and --workers must be >= 1 (got 0, 2)" in capsys.readouterr().err


@pytest.mark.slow
def test_slack_in_the_full_stomach_replays_the_same_motions(tmp_path):
    # The fast stomach's demonstrators in the FEM one: one result per start, and no arrival sooner than 30 steps
    # (the target lies deeper than 75 mm of full-speed insertion whichever stomach holds it).
    path = map_with_list_a(tmp_path, 1)
    (point, per_run), = targets.arrival_steps("A", path, fidelity="full").items()
    assert point == aided("A")[0] and len(per_run) == 1 + targets.PHASES
    assert all(s is None or 30 <= s <= targets.TRIAL_STEPS for s in per_run), per_run


def test_open_loop_replays_the_static_plan_from_load_phases_of_the_moving_stomach(tmp_path):
    # Two of list A's contact-aided targets, their SE demonstrator replayed unchanged from two opposite load
    # phases of DE: the plan still heads for the target (within 15 mm), but the moving wall makes the two
    # phases end differently, and holding the load at its start value (the wall placed, not moving) changes
    # the outcome again; the static stomach has no phases to replay from.
    from mjendo.config import ConfigError

    path = map_with_list_a(tmp_path, 2)
    moving = targets.open_loop("A", "DE", phases=2, path=path)
    held = targets.open_loop("A", "DE", phases=2, hold_load=True, path=path)
    assert moving.shape == held.shape == (2, 2)
    assert np.all(moving < 15.0) and np.all(held < 15.0), (moving, held)
    assert np.all(np.abs(moving[:, 0] - moving[:, 1]) > 0.01), moving
    assert np.any(np.abs(moving - held) > 0.01), (moving, held)
    with pytest.raises(ConfigError, match="need a periodic load"):
        targets.open_loop("A", "SE", phases=2, path=path)
