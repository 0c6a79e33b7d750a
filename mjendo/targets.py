"""Targets on the lumen surface, and the reachability map they are drawn from.

A target is a point on a lumen triangle (three vertex ids and barycentric weights), so it moves with
the wall. ``python -m mjendo.targets map`` measures, for candidate points spread over the whole lumen,

* the **free-space distance**: the closest the tip comes with the stomach removed (FE), over a dense
  quasi-static sweep of insertion x bending direction x bending magnitude and over moving strategies
  (scripted insertions, the demonstrators below, seeded random exploration and the damped-least-squares
  controller aimed at every region still unreached), none of them bound to a trial's length: the tube
  sags over about a second, so a moving scope reaches further, and a longer search only makes the
  contact-aided class more conservative;
* the **reach with the wall within a trial**: the closest the tip comes within one 80-step evaluation
  trial, over a family of scripted demonstrators (bend while inserting at full speed, then optionally
  turn the bending at depth so the tube, lying on the wall, carries the tip round), in the static
  stomach (SE) and from each of four phases of the breathing load (DE): a target counts as reachable only
  if a demonstrator gets there in time from every start, so a policy's success rate can reach 100 %.

Classes: free (free-space distance < 3 mm); contact-aided (>= 10 mm, and reached with the wall within
3 mm in SE and in every DE phase); between (3-10 mm); out of reach (the rest). The map also records for
every contact-aided point what the contact-blind DLS controller aimed at it achieves in an SE trial
(``naive_mm``), and draws the lists: F (the free points, FE's own targets), A (training) and B (held
out), A and B interleaved over the wall with about two thirds contact-aided. It writes
``models/stomach/targets.json``. Task version 0 used lumen vertices (``stomach.json``'s lists);
:func:`load` serves both.
"""

from __future__ import annotations

import argparse
import gzip
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mjendo import anatomy, cli, paths
from mjendo.config import (
    ANATOMY_SETS,
    CURRENT_VERSION,
    FIDELITIES,
    PAPER_ACTION_LIMIT,
    PAPER_EVAL_STEPS,
    PAPER_SUCCESS_MM,
    VERSIONS,
    ConfigError,
    anatomy_set,
    fidelity_preset,
)
from mjendo.units import from_mm, to_mm

MAP_NAME = "targets.json"  # a stomach's map; the committed ones are gzip-compressed (MAP_NAME + ".gz", 7x smaller)


def map_name(version: int = CURRENT_VERSION) -> str:
    """A stomach's map file for a task version: version 1's targets.json, a later version's targets_v<N>.json
    (each version's physics decides which points are reachable, so each has its own map)."""
    return MAP_NAME if version <= 1 else MAP_NAME.replace(".json", f"_v{version}.json")


def targets_file(version: int = CURRENT_VERSION) -> Path:
    """The built-in stomach's committed map of a task version."""
    return paths.STOMACH_DIR / f"{map_name(version)}.gz"


TARGETS_FILE = targets_file()  # the built-in stomach's, of the current task version
FREE_MM = PAPER_SUCCESS_MM  # free: the tip reaches the point in free space (the success distance)
CONTACT_AIDED_MM = 10.0  # contact-aided: free space misses it by this much or more
MIN_CARDIA_MM = 35.0  # targets this close to the cardia are in the scope's blind start
SPACING_MM = PAPER_SUCCESS_MM  # listed targets at least the success distance apart: none counts another as reached
CONTACT_SHARE = 0.65  # of lists A and B, about two thirds: the paper's A reaches 26-34 % outside FE
SPLIT = "AB"  # A and B alike: B holds 50 or more targets, enough to report success per target
MAX_FREE_OTHER = 200  # list F of another stomach's map: enough free targets for FE and training pools


@dataclass
class TargetTable:
    """Target points by id: each a lumen triangle and weights; the named lists hold ids."""

    ids: np.ndarray  # (n,) int
    tris: np.ndarray  # (n, 3) vertex ids
    bary: np.ndarray  # (n, 3) weights, summing to 1
    lists: dict[str, list[int]]
    info: dict
    classes: np.ndarray | None = None  # (n,) the map's class of each point; None for version 0's vertices
    free_mm: np.ndarray | None = None  # (n,) each point's free-space distance (mm); None: not measured (version 0)
    demos: np.ndarray | None = None  # (n,) the demonstrator (DEMOS) recorded reaching it in SE; -1: free, none

    def rows(self, ids) -> np.ndarray:
        """Row of each id in the table."""
        where = {int(i): r for r, i in enumerate(self.ids)}
        return np.array([where[int(i)] for i in ids], dtype=np.int64)

    def listed(self, name: str) -> list[int]:
        """The ids of a list, or of lists joined by '+' ('A+F'), in order, each id once."""
        return list(dict.fromkeys(i for part in name.split("+") for i in self.lists[part]))

    def pool_weights(self, name: str) -> np.ndarray:
        """Relative draw weight of each id of ``listed(name)``: each list of a joined pool ('A+F') is drawn
        equally often, whatever its length (a single list: uniform)."""
        share = {i: 1.0 / len(self.lists[p]) for p in reversed(name.split("+")) for i in self.lists[p]}
        return np.array([share[i] for i in self.listed(name)])

    def contact_aided(self, ids) -> np.ndarray:
        """Whether each id is of the map's contact-aided class (all False for version 0's vertices)."""
        return self.classes[self.rows(ids)] == "contact_aided" if self.classes is not None \
            else np.zeros(len(ids), bool)

    def positions(self, vertices: np.ndarray, ids) -> np.ndarray:
        """Positions of target points given every vertex position (m)."""
        r = self.rows(ids)
        return np.einsum("nk,nkd->nd", self.bary[r], vertices[self.tris[r]])


def map_path(stomach: Path, version: int = CURRENT_VERSION) -> Path:
    """The target map of a stomach's folder for a task version: targets.json (map_name), or the gzip-compressed
    targets.json.gz that the committed stomachs keep (one per benchmark stomach, 7x smaller)."""
    plain = Path(stomach) / map_name(version)
    packed = plain.with_name(plain.name + ".gz")
    return packed if packed.exists() and not plain.exists() else plain


def read_map(path: Path) -> dict:
    """The content of a map file, plain or gzip-compressed (by its suffix)."""
    path = Path(path)
    return json.loads(gzip.decompress(path.read_bytes()) if path.suffix == ".gz" else path.read_text())


def load(version: int = CURRENT_VERSION, path: Path | None = None) -> TargetTable:
    """The target table of a task version (version 0: lumen vertices; later: surface points) from ``path``
    (default: the built-in stomach's map of that version)."""
    if version == 0:
        st = anatomy.load()
        ids = np.array(sorted(set(st.targets_a + st.targets_b)), dtype=np.int64)
        tris = np.repeat(ids[:, None], 3, axis=1)
        bary = np.tile([1.0, 0.0, 0.0], (len(ids), 1))
        return TargetTable(ids, tris, bary, {"A": st.targets_a, "B": st.targets_b, "F": st.targets_a}, {})
    path = Path(path or targets_file(version))
    if not path.exists():
        load_error(path)
    meta = read_map(path)
    pts = meta["points"]
    measured = all("free_mm" in p for p in pts)  # a map written by hand may hold the classes alone
    return TargetTable(np.array([p["id"] for p in pts], dtype=np.int64), np.array([p["tri"] for p in pts]),
                       np.array([p["bary"] for p in pts]), meta["lists"], meta["info"],
                       np.array([p["class"] for p in pts], dtype=object),
                       np.array([p["free_mm"] for p in pts], dtype=float) if measured else None,
                       np.array([p["demos"][0] if p.get("demos") else -1 for p in pts], dtype=np.int64))


def fingerprint(version: int = CURRENT_VERSION, path: Path | None = None) -> str:
    """Short hash of a task version's target lists (ids, triangles, weights): a policy and its results name
    the targets they were trained and evaluated on, as the scene fingerprint names the physics."""
    import hashlib

    table = load(version, path)
    listed = {k: [[int(i), table.tris[r].tolist(), np.round(table.bary[r], 6).tolist()]
                  for i, r in zip(v, table.rows(v), strict=True)] for k, v in sorted(table.lists.items())}
    return hashlib.sha256(json.dumps(listed).encode()).hexdigest()[:12]


# --------------------------------------------------------------------------
# Candidates and measurement.

# Fifteen points per lumen triangle: the interior nodes of its 7-fold subdivision, (i, j, k) / 7 with
# i, j, k >= 1 (no point on an edge, so neighbouring triangles share none); about 3 mm apart on the
# ~20 mm triangles, the success distance, so the lists can hold 50 or more targets each.
GRID = 7
BARY_SAMPLES = np.array([[i, j, GRID - i - j] for i in range(1, GRID) for j in range(1, GRID - i)]) / GRID


def lumen_triangles(st: anatomy.Stomach) -> np.ndarray:
    """Boundary triangles of the wall whose vertices all lie on the lumen."""
    faces = st.mesh.boundary_faces()
    return faces[st.mesh.inner[faces].all(axis=1)]


def candidates(st: anatomy.Stomach) -> tuple[np.ndarray, np.ndarray]:
    """Candidate points: fifteen per lumen triangle (BARY_SAMPLES), away from the cardia."""
    tris = lumen_triangles(st)
    t = np.repeat(tris, len(BARY_SAMPLES), axis=0)
    b = np.tile(BARY_SAMPLES, (len(tris), 1))
    p = np.einsum("nk,nkd->nd", b, st.mesh.points[t])
    keep = np.linalg.norm(p - st.entry, axis=1) > from_mm(MIN_CARDIA_MM)
    return t[keep], b[keep]


def _closest(best: np.ndarray, tip: np.ndarray, points: np.ndarray) -> None:
    np.minimum(best, np.linalg.norm(points - tip, axis=1), out=best)


def _ring(phi: float) -> np.ndarray:
    """Unit cable pattern bending towards ``phi`` (rad about the tube)."""
    return np.array([np.cos(phi), -np.cos(phi), np.sin(phi), -np.sin(phi)])


def _pulls(direction: float, magnitude: float) -> np.ndarray:
    """Cable pulls (m) bending towards ``direction`` (rad about the tube): pull one side, pay out the other."""
    return magnitude * _ring(direction)


def free_tips(version: int, progress: bool = True, anatomy_id=None) -> np.ndarray:
    """Tip positions (m) of the free-space sweep: insertion every 5 mm x 24 bending directions x a slow
    (quasi-static) ramp of the bending from straight to full, with the stomach removed (FE)."""
    from tqdm import tqdm

    from mjendo.sim import Simulator

    sim = Simulator("FE", "fast", version=version,
                    stomach=None if anatomy_id is None else anatomy.stomach_dir(anatomy_id))
    hi = sim.insertion_range[1]
    pull_max = float(sim.cable_pull_max[0])
    dt = sim.model.opt.timestep
    settle, ramp = max(1, int(round(0.3 / dt))), max(1, int(round(0.05 / dt)))
    tips = []
    for ins in tqdm(np.arange(0.0, hi + 1e-9, from_mm(5.0)), desc="free-space sweep", disable=not progress):
        for direction in np.linspace(0, 2 * np.pi, 24, endpoint=False):
            sim.reset()
            sim.set_controls(np.zeros(4), ins)
            sim.step(settle)
            for mag in np.linspace(0, pull_max, 25):
                sim.set_controls(_pulls(direction, mag), ins)
                sim.step(ramp)
                tips.append(sim.tip_pos())
    return np.array(tips)


def free_sweep(version: int, points: np.ndarray, progress: bool = True, anatomy_id=None) -> np.ndarray:
    """Closest approach (m) of the tip to each point in free space, over the sweep of :func:`free_tips`."""
    best = np.full(len(points), np.inf)
    for tip in free_tips(version, progress, anatomy_id):
        _closest(best, tip, points)
    return best


SCRIPTS = [(d, m) for d in np.linspace(0, 2 * np.pi, 12, endpoint=False) for m in (0.0, 0.15, 0.3, 0.4)]
# Demonstrators: (bending direction, bending rate over the first 12 steps while inserting, turn of the
# bending at depth: 0 none, +-1 a quarter turn either way, the step the turn starts). Every one inserts at
# full speed throughout: the deep targets need about 50 of a trial's 80 steps of insertion.
_TWELVE = np.linspace(0, 2 * np.pi, 12, endpoint=False)


def _family(directions: np.ndarray, rates: tuple, turn_steps: tuple, plain: bool = True) -> list[tuple]:
    return ([(d, m, 0, 0) for d in directions for m in rates] if plain else []) + \
        [(d, m, turn, k0) for d in directions for m in rates for turn in (1, -1) for k0 in turn_steps]


DEMOS = _family(_TWELVE, (0.0, 0.2, 0.4), (40, 60))
V1_DEMOS = len(DEMOS)  # 180: version 1's map raced these, and its recorded indices point into them
# From version 2 (every stomach at 10 ms, where the stiffer contact carries the tube less far along the wall) also
# the twelve directions between those, and turns starting at steps 50 and 70 in all 24 directions: 552 in all.
DEMOS += _family(_TWELVE + np.pi / 12, (0.0, 0.2, 0.4), (40, 60)) + \
    _family(np.concatenate([_TWELVE, _TWELVE + np.pi / 12]), (0.2, 0.4), (50, 70), plain=False)


def demos_of(version: int) -> list[tuple]:
    """The demonstrators a task version's map races (version 1: the first 180 of DEMOS)."""
    return DEMOS[:V1_DEMOS] if version <= 1 else DEMOS

PHASES = 4  # DE start phases (of the load cycle) every contact-aided point must be reached from
AIM_NOISE = (0.2, 0.4)  # share of random actions in the aimed passes: the second pass explores more
N_STEPS = 128  # free-space strategies: the training episode's length (longer than a trial: conservative)
TRIAL_STEPS = PAPER_EVAL_STEPS  # reach with the wall: within one evaluation trial


def demo_action(demo: tuple, k: int) -> np.ndarray:
    """Action of demonstrator ``demo`` (an entry of DEMOS) at step ``k``."""
    direction, rate, turn, k0 = demo
    bend = _ring(direction) * rate if k < 12 else np.zeros(4)
    if turn and k >= k0:
        bend = 0.4 * _ring(direction + turn * np.pi / 2)
    return np.concatenate([bend, [0.4]])


PLAN_SIZE = 7


def plan_vector(free_mm: float, demo: int) -> np.ndarray:
    """What a stomach's map plans for a point (``plan_obs``): its free-space distance (mm), whether it needs the
    wall, and the demonstrator recorded reaching it in the static stomach (``demo``, an index into DEMOS; -1: none):
    its bending while inserting (rate / 0.4 times the cosine and sine of its direction about the tube), the direction
    it bends to at depth after its quarter turn (cosine and sine; 0 without a turn) and the share of a trial before
    the turn: demo_action's two cable patterns, each ``[c, -c, s, -s]`` times 0.4."""
    if demo < 0:
        return np.array([free_mm, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    direction, rate, turn, k0 = DEMOS[demo]
    turned = direction + turn * np.pi / 2
    return np.array([free_mm, 1.0, rate / PAPER_ACTION_LIMIT * np.cos(direction),
                     rate / PAPER_ACTION_LIMIT * np.sin(direction), abs(turn) * np.cos(turned),
                     abs(turn) * np.sin(turned), k0 / TRIAL_STEPS if turn else 0.0])


def _reach_job(args) -> tuple[int, np.ndarray]:
    """One worker's part of a reach measurement in ``env`` (SE/DE: with the wall; FE: free space, moving):
    its chunk number and the closest approach (m) of each of its episodes to each point.

    Kinds: "script" (bend, insert all the way at full speed, sweep the bending round at depth), "demo"
    (an entry of DEMOS for ``steps`` steps), "random" (piecewise-constant random actions), "aimed" (the
    DLS controller aimed at one point with a share of random actions; every point's closest approach
    counts) and "naive" (the DLS controller aimed at one point, no noise; only that point's closest
    approach counts: what aiming alone achieves). ``phase``: the load phase every episode starts at.
    """
    chunk, version, env, tris, bary, kind, items, seed, steps, phase, anatomy_id = args
    import torch

    from mjendo.baseline import DLSController
    from mjendo.task import NavigationTask

    torch.set_num_threads(1)
    ids = np.arange(len(tris))
    table = TargetTable(ids, tris, bary, {"A": ids.tolist()}, {})  # the candidates, before any list exists
    task = NavigationTask(env=env, version=version, max_steps=10**6, randomize_phase=False, table=table,
                          target_list="A", anatomy=anatomy_id)
    sim = task.sim
    rows = np.full((len(items), len(tris)), np.inf)
    rng = np.random.default_rng(seed)
    if phase is not None:
        phase = phase * len(task.start_states) // PHASES

    def record(only: int | None = None) -> None:
        if only is None:
            _closest(best, sim.tip_pos(), task.list_positions())
        else:
            best[only] = min(best[only], float(np.linalg.norm(sim.tip_pos() - task.target_pos())))

    for j, item in enumerate(items):
        best = rows[j]
        task.reset(rng, phase)
        if kind == "script":
            direction, mag = item
            for k in range(steps):
                task.step(np.concatenate([_ring(direction) * mag if k < 12 else np.zeros(4), [0.4 * (k >= 12)]]))
                record()
            for k in range(48):
                task.step(np.concatenate([0.4 * _ring(direction + 2 * np.pi * k / 48), [0.0]]))
                record()
        elif kind == "demo":
            for k in range(steps):
                task.step(demo_action(item, k))
                record()
        elif kind == "random":
            a = np.zeros(5)
            for k in range(steps):
                if k % 8 == 0:
                    a = rng.uniform(-0.4, 0.4, 5)
                    a[4] = rng.uniform(-0.1, 0.4)
                res = task.step(a)
                record()
                if res.terminated and res.info["exited"]:
                    break
        else:
            target, noise = item
            task.set_target(int(target))
            dls = DLSController(task)
            dls.reset(task)
            for _k in range(steps):
                res = task.step(rng.uniform(-0.4, 0.4, 5) if rng.random() < noise else dls.act(None, task))
                record(int(target) if kind == "naive" else None)
                if res.terminated:
                    break
    return chunk, rows


def representatives(tris: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """For each lumen triangle, its candidate nearest the centroid (what the aimed passes aim at)."""
    rep: dict[tuple, int] = {}
    for i in np.argsort(-bary.min(axis=1), kind="stable"):
        rep.setdefault(tuple(tris[i]), int(i))
    return np.array(sorted(rep.values()), dtype=np.int64)


def free_reach(version: int, tris: np.ndarray, bary: np.ndarray, episodes: int, seed: int, progress: bool = True,
               workers: int = 2, start: np.ndarray | None = None, anatomy_id=None) -> np.ndarray:
    """Closest approach (m) of the tip to each point in free space (FE), over every moving strategy.

    Scripted insertions, the demonstrators and seeded random exploration first; then two aimed passes at
    the triangles that still hold a point beyond 3 mm. ``start``: closest approaches already measured (the
    quasi-static sweep). Work is spread over ``workers`` processes; the result does not depend on their number.
    """
    best = np.full(len(tris), np.inf) if start is None else start.copy()
    for phase, (kind, items) in enumerate([("script", SCRIPTS), ("demo", demos_of(version)),
                                           ("random", list(range(episodes)))]):
        np.minimum(best, _pool("FE", version, tris, bary, kind, items, seed * 1000 + phase * 100, progress,
                               workers, N_STEPS, anatomy_id=anatomy_id).min(0), out=best)
    reps = representatives(tris, bary)
    for phase, noise in enumerate(AIM_NOISE, start=3):
        open_tris = {tuple(t) for t in tris[best >= from_mm(PAPER_SUCCESS_MM)]}
        aims = [(int(i), noise) for i in reps if tuple(tris[i]) in open_tris]
        np.minimum(best, _pool("FE", version, tris, bary, "aimed", aims, seed * 1000 + phase * 100, progress,
                               workers, N_STEPS, anatomy_id=anatomy_id).min(0), out=best)
    return best


def wall_reach(version: int, tris: np.ndarray, bary: np.ndarray, seed: int, progress: bool = True,
               workers: int = 2, anatomy_id=None) -> np.ndarray:
    """Closest approach (m) of every demonstrator to every point within a trial, in SE then in each DE phase:
    shape (1 + PHASES, len(demos_of(version)), points)."""
    runs = [("SE", None)] + [("DE", p) for p in range(PHASES)]
    demos = demos_of(version)
    return np.array([_pool(env, version, tris, bary, "demo", demos, seed * 1000 + 500 + k, progress, workers,
                           TRIAL_STEPS, phase=p, anatomy_id=anatomy_id) for k, (env, p) in enumerate(runs)])


def naive_reach(version: int, tris: np.ndarray, bary: np.ndarray, points, seed: int, progress: bool = True,
                workers: int = 2, anatomy_id=None) -> np.ndarray:
    """Closest approach (m) of the contact-blind DLS controller aimed at each of ``points`` in an SE trial."""
    return _pool("SE", version, tris, bary, "naive", [(int(t), 0.0) for t in points], seed * 1000 + 900, progress,
                 workers, TRIAL_STEPS, anatomy_id=anatomy_id).min(0)


def _pool(env, version, tris, bary, kind, items, seed, progress, workers, steps, phase=None,
          anatomy_id=None) -> np.ndarray:
    """Closest approach (m) of each episode (one per item, in order) to each point: (len(items), points)."""
    from multiprocessing import get_context

    from tqdm import tqdm

    chunks = 16
    rows = np.full((len(items), len(tris)), np.inf)
    if not items:
        return rows
    jobs = [(i, version, env, tris, bary, kind, items[i::chunks], seed + i, steps, phase, anatomy_id)
            for i in range(chunks)]
    label = f"{env} {kind} ({len(items)})" + ("" if phase is None else f" phase {phase + 1}/{PHASES}")
    with get_context("spawn").Pool(workers) as pool:
        for i, part in tqdm(pool.imap_unordered(_reach_job, jobs), total=len(jobs), desc=label,
                            disable=not progress):
            rows[i::chunks] = part
    return rows


def classify(free_mm: np.ndarray, wall_mm: np.ndarray, phase_mm: np.ndarray) -> np.ndarray:
    """Each point's class (module docstring) from its free-space, SE and worst-DE-phase distances (mm)."""
    cls = np.full(len(free_mm), "out_of_reach", dtype=object)
    cls[(free_mm >= FREE_MM) & (free_mm < CONTACT_AIDED_MM)] = "between"
    reached = (wall_mm < PAPER_SUCCESS_MM) & (phase_mm < PAPER_SUCCESS_MM)
    cls[(free_mm >= CONTACT_AIDED_MM) & reached] = "contact_aided"
    cls[free_mm < FREE_MM] = "free"
    return cls


def replay_demo(task, demo: tuple, point: int, start: int | None) -> tuple[int | None, float]:
    """Run demonstrator ``demo`` for one trial towards ``point`` from start state ``start`` (None: the only one):
    the step (1-80) at which it first comes within the success distance (None: never) and its closest approach
    (mm) within the trial."""
    task.reset(np.random.default_rng(0), start)
    task.set_target(point)
    first, closest = None, np.inf
    for k in range(TRIAL_STEPS):
        task.step(demo_action(demo, k))
        closest = min(closest, task.distance_mm())
        if first is None and closest < PAPER_SUCCESS_MM:
            first = k + 1
    return first, closest


def _listed_aided(list_name: str, path: Path) -> tuple[dict, list[int]]:
    meta = read_map(path)
    points = {p["id"]: p for p in meta["points"]}
    return points, [i for i in meta["lists"][list_name] if points[i]["class"] == "contact_aided"]


def _starts(fidelity: str, list_name: str, phases: int = PHASES, env: str = "DE", anatomy_id=None,
            timestep: float | None = None, version: int = CURRENT_VERSION):
    """The trial starts every contact-aided point must be reached from: SE, then ``phases`` evenly spaced load
    phases of ``env`` (the map's 4 of DE, or more to look between them, or a stronger load), in the built-in
    stomach or ``anatomy_id``'s, at the stomach's own physics step or ``timestep``; yields the task, the start
    state (None: the only one) and a label."""
    from mjendo.task import NavigationTask

    for name, phase in [("SE", None)] + [(env, p) for p in range(phases)]:
        task = NavigationTask(env=name, target_list=list_name, max_steps=10**6, randomize_phase=False,
                              fidelity=fidelity, anatomy=anatomy_id, timestep_s=timestep, version=version)
        start = None if phase is None else phase * len(task.start_states) // phases
        yield task, start, name if phase is None else f"{name} phase {phase}/{phases}"


def static_demos(list_name: str, path: Path = TARGETS_FILE) -> list[tuple[int, int]]:
    """(demonstrator, point) for each of the list's contact-aided points: the demonstrator (an index into
    DEMOS) the map recorded reaching it in the static stomach, SE."""
    points, listed = _listed_aided(list_name, path)
    return [(points[i]["demos"][0], i) for i in listed]


def recorded_demos(list_name: str, path: Path = TARGETS_FILE) -> list[int]:
    """The demonstrators the map recorded for the list's contact-aided points (any start): the ones worth
    racing from start phases the map did not try."""
    points, listed = _listed_aided(list_name, path)
    return sorted({d for i in listed for d in points[i]["demos"]})


def stomach_map(anatomy_id=None, version: int = CURRENT_VERSION) -> Path:
    """The target map of the built-in stomach (None), a generated one (its seed) or a user's (its folder)."""
    return map_path(anatomy.stomach_dir(anatomy_id), version)


def arrival_steps(list_name: str, path: Path | None = None, fidelity: str = "fast",
                  anatomy_id=None, version: int = CURRENT_VERSION) -> dict[int, list[int | None]]:
    """Step (1-80) at which each listed contact-aided point's recorded demonstrator first comes within the
    success distance, in SE and from each DE load phase (None: not within the trial). The recorded one is
    the demonstrator that came closest, not necessarily the fastest: an upper bound on the time a known
    way there needs, so on how little slack a policy has. In the full stomach (the map is measured in the
    fast one) the same motions show whether, and when, the FEM wall lets the tube get there too."""
    points, listed = _listed_aided(list_name, path or stomach_map(anatomy_id, version))
    steps: dict[int, list[int | None]] = {i: [] for i in listed}
    for run, (task, start, where) in enumerate(_starts(fidelity, list_name, anatomy_id=anatomy_id, version=version)):
        for i in listed:
            steps[i].append(replay_demo(task, DEMOS[points[i]["demos"][run]], i, start)[0])
        print(f"  {fidelity} {where}: {len(listed)} demonstrators replayed ({run + 1}/{1 + PHASES})", flush=True)
    return steps


def fastest_arrivals(list_name: str, path: Path | None = None, demos: list[int] | None = None,
                     phases: int = PHASES, env: str = "DE", anatomy_id=None, fidelity: str = "fast",
                     timestep: float | None = None, version: int = CURRENT_VERSION) -> dict[int, list[int | None]]:
    """Like :func:`arrival_steps`, but the earliest arrival over every demonstrator of ``demos`` (indices into
    DEMOS; None: all the version's, demos_of), not the recorded one's: the fastest known way to each point from SE
    and each of ``phases`` starts of ``env`` (DE, or UE1 and UE2's stronger loads), in a fast stomach at its own step or
    ``timestep`` (the map's classes were measured at the fast stomach's own). The target is not physical, so
    one replay per demonstrator and start measures every listed point."""
    points, listed = _listed_aided(list_name, path or stomach_map(anatomy_id, version))
    demos = list(range(len(demos_of(version)))) if demos is None else demos
    steps: dict[int, list[int | None]] = {i: [] for i in listed}
    starts = _starts(fidelity, list_name, phases, env, anatomy_id, timestep, version)
    for run, (task, start, where) in enumerate(starts):
        rows = np.array([int(np.flatnonzero(task.targets == i)[0]) for i in listed])
        first = np.full(len(listed), TRIAL_STEPS + 1)
        for d in demos:
            task.reset(np.random.default_rng(0), start)
            for k in range(min(TRIAL_STEPS, int(first.max()) - 1)):  # no demonstrator can beat an arrival by then
                task.step(demo_action(DEMOS[d], k))
                dist = to_mm(np.linalg.norm(task.list_positions()[rows] - task.sim.tip_pos(), axis=1))
                first = np.where(dist < PAPER_SUCCESS_MM, np.minimum(first, k + 1), first)
        for i, s in zip(listed, first, strict=True):
            steps[i].append(int(s) if s <= TRIAL_STEPS else None)
        print(f"  {where}: {len(demos)} demonstrators replayed ({run + 1}/{1 + phases})", flush=True)
    return steps


SLACK_BINS = ((1, 60), (61, 70), (71, 75), (76, TRIAL_STEPS))  # latest arrival's step: 20, 10, 5 or fewer to spare


def success_by_slack(latest: dict[int, int | None], per_target: Path) -> str:
    """A study's success per contact-aided target (its per_target.csv), by how late the fastest known way
    arrives from the worst start: whether a policy's misses are the targets that leave it no time."""
    import csv

    with open(per_target) as f:
        rows = [r for r in csv.DictReader(f) if int(r["target"]) in latest]
    if not rows:
        raise ConfigError(f"{per_target} holds none of this list's contact-aided targets: give the "
                          "per_target.csv of a study over the same list (its envs DE or SE for list A)")
    lines = ["policy, env: success on the contact-aided targets whose latest known arrival is at step " +
             ", ".join(f"{lo}-{hi}" for lo, hi in SLACK_BINS) + " (targets)"]
    for key in dict.fromkeys((r["policy"], r["env"]) for r in rows):
        cells = []
        for lo, hi in SLACK_BINS:
            sel = [r for r in rows if (r["policy"], r["env"]) == key and lo <= (latest[int(r["target"])] or 0) <= hi]
            trials = sum(int(r["trials"]) for r in sel)
            won = sum(float(r["success_pct"]) * int(r["trials"]) / 100 for r in sel)
            cells.append(f"{100 * won / trials:.1f} % ({len(sel)})" if trials else "- (0)")
        lines.append(f"  {key[0]}, {key[1]}: " + ", ".join(cells))
    return "\n".join(lines)


def _slack_report(list_name: str, fidelity: str, fastest: bool = False, per_target: Path | None = None,
                  phases: int = PHASES, demos: list[int] | None = None, env: str = "DE", anatomy_id=None,
                  timestep: float | None = None, version: int = CURRENT_VERSION) -> str:
    """``slack``'s summary; for the full stomach also each trial's arrival against the fast stomach's; from
    more start phases than the map's or at another physics step, how many (target, start) pairs a known way
    reaches at all."""
    steps = fastest_arrivals(list_name, demos=demos, phases=phases, env=env, anatomy_id=anatomy_id,
                             fidelity=fidelity, timestep=timestep, version=version) if fastest \
        else arrival_steps(list_name, fidelity=fidelity, anatomy_id=anatomy_id, version=version)
    latest = {i: max(s) if None not in s else None for i, s in steps.items()}
    arrived = np.array([s for s in latest.values() if s is not None])
    which = ("fastest of all demonstrators" if demos is None else f"fastest of {len(demos)} demonstrators") \
        if fastest else "recorded demonstrator"
    step = "" if timestep is None else f" at a {1000 * timestep:g} ms physics step"
    line = (f"list {list_name}, {fidelity} stomach{step}: {len(latest)} contact-aided targets; the {which} arrives "
            f"(latest of SE and the {phases} {env} phases) by step {TRIAL_STEPS} at {len(arrived)}")
    if len(arrived):
        line += (f"; median step {np.median(arrived):.0f}, quartiles {np.percentile(arrived, 25):.0f}-"
                 f"{np.percentile(arrived, 75):.0f}, after step 70 at {np.mean(arrived > 70):.0%}")
    lines = [line]
    if phases != PHASES or env != "DE" or timestep is not None:
        reached = np.array([[a is not None for a in s] for s in steps.values()])
        lines.append(f"(target, start) pairs a known way reaches within the trial: {reached.mean():.1%} of "
                     f"{reached.size}; {env} starts only: {reached[:, 1:].mean():.1%}; targets missed from some start: "
                     f"{(~reached).any(axis=1).sum()}")
    if fidelity != "fast" and not fastest:
        fast = arrival_steps(list_name, anatomy_id=anatomy_id, version=version)
        pairs = [(a, b) for i in steps for a, b in zip(fast[i], steps[i], strict=True) if a is not None]
        late = np.array([b - a for a, b in pairs if b is not None])
        line = (f"the same motions, {len(pairs)} trials that arrive in the fast stomach: {len(late)} arrive within "
                f"the trial in the {fidelity} one")
        if len(late):
            line += (f", {np.median(late):+.0f} steps later (median; quartiles {np.percentile(late, 25):+.0f} to "
                     f"{np.percentile(late, 75):+.0f})")
        lines.append(line)
    if per_target is not None:
        lines.append(success_by_slack(latest, per_target))
    return "\n".join(lines)


def known_way_ceiling(list_name: str, anatomy_id=None, phases: int = 8, env: str = "DE",
                      path: Path | None = None) -> dict:
    """How much of a stomach's list a known way reaches within a trial: its recorded demonstrators raced, the
    fastest kept, from ``phases`` starts of ``env`` for each contact-aided target; free targets counted as
    reached (free space brings the tip within 3 mm of them). The ceiling is the share of (target, start) pairs
    over the list, each target weighed as an evaluation tries them: equally."""
    path = path or stomach_map(anatomy_id)
    meta = read_map(path)
    points = {p["id"]: p for p in meta["points"]}
    listed = meta["lists"][list_name]
    steps = fastest_arrivals(list_name, path, recorded_demos(list_name, path), phases, env, anatomy_id)
    reached = {i: np.mean([a is not None for a in s[1:]]) for i, s in steps.items()}  # the moving stomach's starts
    latest = [max(s[1:]) for s in steps.values() if None not in s[1:]]
    return {"targets": len(listed), "contact_aided": len(steps),
            "free": sum(points[i]["class"] == "free" for i in listed),
            "pairs_reached": float(np.mean(list(reached.values()))) if reached else 1.0,
            "missed_somewhere": sum(r < 1 for r in reached.values()),
            "median_latest": float(np.median(latest)) if latest else None,
            "ceiling": float(np.mean([reached.get(i, 1.0) for i in listed]))}


def print_ceilings(list_name: str, anatomies: list, phases: int, env: str, per_anatomy: Path | None) -> None:
    """``slack --ceiling``: each stomach's known-way ceiling as it is measured, beside a study's success there
    (its per_anatomy.csv), then how the two go together across stomachs."""
    import csv

    success: dict[str, dict[str, float]] = {}
    if per_anatomy is not None:
        with open(per_anatomy) as f:
            for r in csv.DictReader(f):
                if r["env"] == env:
                    success.setdefault(r["policy"], {})[r["anatomy"]] = float(r["success_pct"])
    print(f"list {list_name}, {env}, {phases} start phases: stomach, targets (contact-aided), (target, start) pairs "
          "a known way reaches, contact-aided targets missed from some start, median latest arrival, ceiling of "
          "the list" + "".join(f", {p} success" for p in success), flush=True)
    ceilings, latest = {}, {}
    for a in anatomies:
        c = known_way_ceiling(list_name, a, phases, env)
        ceilings[str(a)], latest[str(a)] = c["ceiling"], c["median_latest"]
        median = "-" if c["median_latest"] is None else f"{c['median_latest']:.0f}"
        print(f"  {a}: {c['targets']} ({c['contact_aided']}), {c['pairs_reached']:.1%}, {c['missed_somewhere']}, "
              f"step {median}, {c['ceiling']:.1%}" +
              "".join(f", {per.get(str(a), float('nan')):.1f} %" for per in success.values()), flush=True)
    print(f"  mean ceiling {np.mean(list(ceilings.values())):.1%}")
    for policy, per in success.items():  # which stomachs are hard: those a known way barely reaches, or late
        both = [(ceilings[a], latest[a], per[a]) for a in ceilings if a in per and latest[a] is not None]
        if len(both) > 2:
            x, t, y = np.array(both).T
            with_ceiling = f"{np.corrcoef(x, y)[0, 1]:+.2f}" if np.ptp(x) > 0 else "- (every ceiling equal)"
            print(f"  {policy}: correlation of success across {len(both)} stomachs with the ceiling {with_ceiling}, "
                  f"with the median latest arrival {np.corrcoef(t, y)[0, 1]:+.2f}")


def open_loop(list_name: str, env: str = "DE", phases: int = 8, hold_load: bool = False,
              path: Path = TARGETS_FILE) -> np.ndarray:
    """Closest approach (mm) within a trial of each listed contact-aided point's static-stomach demonstrator
    (the one the map recorded for SE, which reaches it there), replayed unchanged from ``phases`` evenly
    spaced phases of ``env``'s load; shape (points, phases). Where the moving wall spoils a plan that works in
    the still stomach, a policy has to adapt: closing the loop is part of the task. ``hold_load`` keeps the
    load at its value at the start for the whole trial (the wall placed as at that phase, but not moving
    during the trial), which separates the wall's motion within a trial from where the load has put it."""
    from mjendo.sim import square_wave
    from mjendo.task import NavigationTask

    points, listed = _listed_aided(list_name, path)
    task = NavigationTask(env=env, target_list=list_name, max_steps=10**6, randomize_phase=False)
    sim, n = task.sim, len(task.start_states)
    if n == 1 or not 1 <= phases <= n:
        raise ConfigError(f"{env} has {n} start phase(s): open-loop replays need a periodic load (DE, UE1, UE2) "
                          f"and 1 to {n} phases")
    closest = np.empty((len(listed), phases))
    for k in range(phases):
        start = k * n // phases
        if hold_load:  # an integration state starts with its time: the load's sign at the start, held
            sim.set_load(np.sign(square_wave(task.start_states[start][0], 1.0, sim.half_period)), np.inf)
        for j, i in enumerate(listed):
            closest[j, k] = replay_demo(task, DEMOS[points[i]["demos"][0]], i, start)[1]
        sim.set_load()
    return closest


def spread(points: np.ndarray, order: np.ndarray, spacing: float) -> list[int]:
    """Greedy subset of ``order`` whose points lie at least ``spacing`` apart."""
    kept: list[int] = []
    for i in order:
        if all(np.linalg.norm(points[i] - points[j]) >= spacing for j in kept):
            kept.append(int(i))
    return kept


def draw_lists(points: np.ndarray, cls: np.ndarray, st: anatomy.Stomach, seed: int) -> dict[str, list[int]]:
    """Lists F (free points), A and B (contact-aided and free, about two thirds contact-aided, interleaved)."""
    rng = np.random.default_rng(seed)
    spacing = from_mm(SPACING_MM)
    aided = spread(points, rng.permutation(np.flatnonzero(cls == "contact_aided")), spacing)
    free = spread(points, rng.permutation(np.flatnonzero(cls == "free")), spacing)
    n_free = min(len(free), int(round(len(aided) * (1 - CONTACT_SHARE) / CONTACT_SHARE)))
    a_aided, b_aided = anatomy.split_targets(points, st.entry, st.axis, aided, SPLIT)
    a_free, b_free = anatomy.split_targets(points, st.entry, st.axis, free[:n_free], SPLIT)
    return {"A": sorted(a_aided + a_free), "B": sorted(b_aided + b_free), "F": sorted(free)}


def list_info(cls: np.ndarray, lists: dict) -> dict:
    aided = set(np.flatnonzero(cls == "contact_aided").tolist())
    return {"contact_aided_share": {k: round(len(aided & set(v)) / max(1, len(v)), 3) for k, v in lists.items()},
            "sizes": {k: len(v) for k, v in lists.items()}}


def redraw(meta: dict, seed: int, version: int = CURRENT_VERSION) -> dict:
    """Draw the lists again from a map's measured classes (no simulation): `python -m mjendo.targets lists`."""
    from mjendo.task import free_targets

    st = anatomy.load()
    pts = meta["points"]
    tris, bary = np.array([p["tri"] for p in pts]), np.array([p["bary"] for p in pts])
    rest = np.einsum("nk,nkd->nd", bary, free_targets("fast", version)[tris])
    cls = np.array([p["class"] for p in pts], dtype=object)
    lists = draw_lists(rest, cls, st, seed)
    meta["info"].update(list_info(cls, lists), lists_command=f"python -m mjendo.targets lists --seed {seed}"
                        + ("" if version == CURRENT_VERSION else f" --version {version}"))
    return {**meta, "lists": lists}


def make_map(episodes: int, seed: int, progress: bool = True, anatomy_id=None, workers: int = 2,
             version: int = CURRENT_VERSION) -> dict:
    """Measure every candidate and draw the lists; the content of targets.json.

    ``anatomy_id``: another stomach (TaskConfig.anatomy); its map keeps only the listed points' records,
    with list F cut to MAX_FREE_OTHER, so a benchmark of many stomachs stays small.
    """
    from mjendo.task import free_targets

    folder = anatomy.stomach_dir(anatomy_id)
    st = anatomy.load(folder)
    tris, bary = candidates(st)
    t0 = time.time()
    where = free_targets("fast", version, None if anatomy_id is None else folder)
    rest = np.einsum("nk,nkd->nd", bary, where[tris])  # where FE's points float
    static_mm = to_mm(free_sweep(version, rest, progress, anatomy_id))
    # Free space reaches further moving than settling (the tube sags over about a second): the free-space
    # distance is the closer of the quasi-static sweep and the same strategies as with the wall, in FE.
    free_mm = to_mm(free_reach(version, tris, bary, episodes, seed, progress, workers,
                               start=from_mm(static_mm), anatomy_id=anatomy_id))
    # (SE + DE phases, demonstrators, points)
    demos = wall_reach(version, tris, bary, seed, progress, workers, anatomy_id=anatomy_id)
    per_run = to_mm(demos.min(1))
    wall_mm, phase_mm = per_run[0], per_run[1:].max(0)
    which = demos.argmin(1)  # the demonstrator that comes closest, per run and point
    cls = classify(free_mm, wall_mm, phase_mm)
    aided = np.flatnonzero(cls == "contact_aided")
    naive_mm = np.full(len(tris), np.nan)
    naive_mm[aided] = to_mm(naive_reach(version, tris, bary, aided, seed, progress, workers,
                                        anatomy_id=anatomy_id)[aided])
    lists = draw_lists(rest, cls, st, seed)
    if anatomy_id is not None:
        lists["F"] = sorted(lists["F"][:MAX_FREE_OTHER])
    counts = {c: int(np.sum(cls == c)) for c in ("free", "between", "contact_aided", "out_of_reach")}
    info = {
        "physics_step_s": fidelity_preset("fast", version).timestep_s,
        "rule": (f"free: free-space distance < {FREE_MM} mm; contact_aided: >= {CONTACT_AIDED_MM} mm and reached "
                 f"with the wall within {PAPER_SUCCESS_MM} mm within {TRIAL_STEPS} steps by a demonstrator, in SE "
                 f"and from each of {PHASES} DE load phases; listed points at least {SPACING_MM} mm apart"),
        "command": f"python -m mjendo.targets map --episodes {episodes} --seed {seed}"
                   + ("" if anatomy_id is None else f" --anatomy {anatomy_id}")
                   + ("" if version == CURRENT_VERSION else f" --version {version}"),
        "classes": counts,
        "seconds": round(time.time() - t0, 1),
        **list_info(cls, lists),
    }
    info["contact_aided_reached_by_aiming"] = int(np.sum(naive_mm[aided] < PAPER_SUCCESS_MM))
    points = [{"id": i, "tri": [int(x) for x in tris[i]], "bary": [round(float(x), 6) for x in bary[i]],
               "static_mm": round(float(static_mm[i]), 2), "free_mm": round(float(free_mm[i]), 2),
               "wall_mm": round(float(wall_mm[i]), 2), "phase_mm": round(float(phase_mm[i]), 2),
               "naive_mm": None if np.isnan(naive_mm[i]) else round(float(naive_mm[i]), 2), "class": cls[i],
               # index into DEMOS of the demonstrator that reaches a contact-aided point, in SE then per DE phase
               "demos": [int(k) for k in which[:, i]] if cls[i] == "contact_aided" else None}
              for i in range(len(tris))]
    if anatomy_id is not None:
        listed = {i for v in lists.values() for i in v}
        points = [p for p in points if p["id"] in listed]
    return {"version": version, "info": info, "lists": lists, "points": points}


def figure(out: Path, path: Path = TARGETS_FILE) -> Path:
    """The free-space workspace of task versions 0 and 1 and the map's classes (docs/media/targets.png)."""
    from mjendo import figures
    from mjendo.task import free_targets

    st = anatomy.load()
    table = load(CURRENT_VERSION, path)
    meta = read_map(path)
    rest = free_targets("fast", CURRENT_VERSION)
    points = np.einsum("nk,nkd->nd", table.bary, rest[table.tris])
    classes = np.array([p["class"] for p in meta["points"]], dtype=object)
    lists = {k: table.rows(v) for k, v in table.lists.items()}
    spaces = {f"task version {v}": free_tips(v) for v in (0, CURRENT_VERSION)}
    return figures.target_map(rest[st.mesh.inner], points, classes, lists, spaces, Path(out))


def write_map(meta: dict, out: Path) -> None:
    text = json.dumps(meta, indent=None, separators=(",", ":")).replace('{"id"', '\n{"id"') + "\n"
    if Path(out).suffix == ".gz":
        Path(out).write_bytes(gzip.compress(text.encode(), mtime=0))  # mtime 0: the same map, the same bytes
    else:
        Path(out).write_text(text)


def benchmark_maps(name: str, episodes: int, seed: int, workers: int = 2, version: int = CURRENT_VERSION) -> None:
    """The maps of a benchmark set's stomachs, each committed with its stomach under models/anatomies/seed-N/.

    Resumable: a stomach whose map exists is skipped, so a stopped run goes on where it stopped.
    """
    for k in anatomy_set(name):  # a benchmark set's into the tree; a list of your own's into the cache
        folder = paths.ANATOMIES_DIR / f"seed-{k}" if name in ANATOMY_SETS else anatomy.anatomy_dir(k)
        if map_path(folder, version).exists():
            print(f"{folder}: map exists, skipped", flush=True)
            continue
        if not (folder / "stomach.json").exists():
            anatomy.save(anatomy.generate(k), folder)
        t0 = time.time()
        meta = make_map(episodes, seed, progress=False, anatomy_id=k, workers=workers, version=version)
        write_map(meta, folder / f"{map_name(version)}.gz")
        sizes = ", ".join(f"{n} {len(v)}" for n, v in meta["lists"].items())
        print(f"{folder}: {meta['info']['classes']}, lists {sizes} ({time.time() - t0:.0f} s)", flush=True)


def require_maps(anatomy_id, version: int = CURRENT_VERSION) -> None:
    """A ConfigError naming the command unless every stomach of ``anatomy_id`` (None, a seed, a set or a folder)
    has its map: checked before a job starts, not as the same error in each of its trials."""
    for member in (m for m in anatomy.members(anatomy_id) if m is not None):
        path = map_path(anatomy.stomach_dir(member), version)
        if not path.exists():
            load_error(path)


def load_error(path: Path):
    raise ConfigError(f"{path} is missing; measure the map first with `python -m mjendo.targets map` "
                      "(another stomach's: `--anatomy SEED_OR_FOLDER`)")


def anatomy_arg(text: str) -> int | str:
    """--anatomy: a generated stomach's seed, a set (a benchmark set's name or seeds as 110-119), or a folder."""
    return int(text) if text.isdigit() else text


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m mjendo.targets", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    m = sub.add_parser("map", help="measure every candidate point and write the target lists (targets.json)")
    m.add_argument("--episodes", type=int, default=400, help="random exploration episodes in free space")
    m.add_argument("--seed", type=int, default=0)
    m.add_argument("--anatomy", type=anatomy_arg, help="another stomach: a generated one's seed, a built folder, or "
                   f"a set ({', '.join(ANATOMY_SETS)}: every stomach of it, into models/anatomies/; seeds of your own "
                   "as 110-119 or 3,5,8-9: into the cache)")
    m.add_argument("--out", type=Path, help="default: targets.json in the stomach's folder")
    m.add_argument("--workers", type=int, default=2, help="processes (the map does not depend on their number)")
    version_help = (f"task version (default {CURRENT_VERSION}): its physics decides which points are reachable, "
                    "and each version has its own map (map_name)")
    map_versions = sorted(v for v in VERSIONS if v >= 1)  # version 0's targets are lumen vertices, no map
    m.add_argument("--version", type=int, default=CURRENT_VERSION, choices=map_versions, help=version_help)
    f = sub.add_parser("figure", help="free-space workspaces (versions 0 and 1) and the classified points")
    f.add_argument("--out", type=Path, default=paths.DATA / "docs" / "media" / "targets.png")
    sl = sub.add_parser("slack", help="the step at which each listed contact-aided target's demonstrator arrives")
    sl.add_argument("--list", default="A", choices=("A", "B"))
    sl.add_argument("--version", type=int, default=CURRENT_VERSION, choices=map_versions, help=version_help)
    sl.add_argument("--fidelity", default="fast", choices=tuple(FIDELITIES),
                    help="full: the same motions in the FEM stomach (about 40 min on one core)")
    sl.add_argument("--fastest", action="store_true", help="the earliest arrival over all the version's "
                    f"demonstrators ({V1_DEMOS} for version 1, {len(DEMOS)} from version 2), "
                    "not the recorded one's (a fast stomach; up to 900 trials of 80 steps)")
    sl.add_argument("--timestep", type=float, help="with --fastest, the physics step (s) instead of the "
                    "stomach's own: is the map's contact-aided class a property of the step it was measured at")
    sl.add_argument("--per-target", type=Path, help="a study's per_target.csv: its success on these targets "
                    "by how late the known way arrives")
    sl.add_argument("--phases", type=int, default=PHASES, help=f"start phases of --env, evenly spaced over the load "
                    f"cycle (with --fastest; the map checked {PHASES}): is every target reachable between them too")
    sl.add_argument("--env", default="DE", choices=("DE", "UE1", "UE2"), help="with --fastest, the moving stomach "
                    "whose phases to start from (the map checked DE)")
    sl.add_argument("--recorded-demos", action="store_true", help="with --fastest, race only the demonstrators "
                    "the map recorded for the list's targets instead of all the version's")
    sl.add_argument("--anatomy", type=anatomy_arg, help="another stomach (a generated one's seed or a built "
                    f"folder), or with --ceiling a benchmark set ({', '.join(ANATOMY_SETS)})")
    sl.add_argument("--ceiling", action="store_true", help="per stomach, the share of the list a known way "
                    "reaches within a trial from --phases starts (its recorded demonstrators raced)")
    sl.add_argument("--per-anatomy", type=Path, help="with --ceiling, a study's per_anatomy.csv: its success "
                    "per stomach beside the ceiling")
    ol = sub.add_parser("open-loop", help="each listed contact-aided target's static-stomach demonstrator replayed "
                        "unchanged from phases of the moving stomach: does the plan survive the wall's motion")
    ol.add_argument("--list", default="A", choices=("A", "B"))
    ol.add_argument("--env", default="DE", choices=("DE", "UE1", "UE2"))
    ol.add_argument("--phases", type=int, default=8, help="start phases, evenly spaced over the load cycle")
    ol.add_argument("--hold-load", action="store_true", help="hold the load at its value at the start: the wall "
                    "placed as at that phase but not moving during the trial")
    d = sub.add_parser("lists", help="draw lists F, A and B again from the map's measured classes (no simulation)")
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--version", type=int, default=CURRENT_VERSION, choices=map_versions, help=version_help)
    d.add_argument("--out", type=Path, help="default: the built-in stomach's map of --version")
    args = ap.parse_args(argv)

    def command() -> None:
        if args.cmd == "figure":
            print(f"wrote {figure(args.out)}")
            return
        if args.cmd == "slack":
            from mjendo.task import PHASES_PER_CYCLE

            if args.fastest and args.fidelity == "full":
                raise ConfigError("--fastest races up to 900 trials of 80 steps, hours in the FEM stomach: give a "
                                  "fast --fidelity (fast, fast-compliant, fast-coarse) or drop --fastest")
            if args.timestep is not None and not args.fastest:
                raise ConfigError("--timestep goes with --fastest (the recorded demonstrators were chosen at the "
                                  "stomach's own step): add --fastest")
            for given, name in ((args.per_target, "per_target.csv"), (args.per_anatomy, "per_anatomy.csv")):
                if given is not None and not given.is_file():
                    raise ConfigError(f"{given} does not exist: give the {name} a study wrote "
                                      f"(python -m mjendo.study ... --out DIR writes DIR/{name})")
            if not 1 <= args.phases <= PHASES_PER_CYCLE:
                raise ConfigError(f"--phases {args.phases}: give 1 to {PHASES_PER_CYCLE} start phases per load cycle")
            if args.ceiling:
                print_ceilings(args.list, anatomy.members(args.anatomy), args.phases, args.env, args.per_anatomy)
                return
            if anatomy_set(args.anatomy) is not None:
                raise ConfigError(f"--anatomy {args.anatomy} is a set of stomachs: add --ceiling for a line per "
                                  "stomach, or give one stomach's seed")
            if args.per_anatomy is not None:
                raise ConfigError("--per-anatomy goes with --ceiling (success per stomach beside its ceiling)")
            if not args.fastest and (args.phases != PHASES or args.recorded_demos or args.env != "DE"):
                raise ConfigError(f"the map recorded a demonstrator for {PHASES} DE phases only: add --fastest to "
                                  "race demonstrators from other phases, loads or a subset of them")
            demos = recorded_demos(args.list, stomach_map(args.anatomy, args.version)) if args.recorded_demos else None
            print(_slack_report(args.list, args.fidelity, args.fastest, args.per_target, args.phases, demos,
                                args.env, args.anatomy, args.timestep, args.version))
            return
        if args.cmd == "open-loop":
            closest = open_loop(args.list, args.env, args.phases, args.hold_load)
            hit = closest < PAPER_SUCCESS_MM
            held = " (load held at its start value)" if args.hold_load else ""
            print(f"list {args.list}, {args.env}{held}: {len(closest)} contact-aided targets, each reached in SE by "
                  f"its recorded demonstrator; replayed unchanged from {args.phases} load phases it comes within "
                  f"{PAPER_SUCCESS_MM:g} mm in {hit.mean():.1%} of the {hit.size} trials (every phase: "
                  f"{hit.all(axis=1).mean():.1%} of the targets, none: {(~hit).all(axis=1).mean():.1%}); closest "
                  f"approach median {np.median(closest):.2f} mm, 90th percentile {np.percentile(closest, 90):.2f} mm")
            return
        if args.cmd == "map" and (args.episodes < 1 or args.workers < 1):
            raise ConfigError(f"--episodes and --workers must be >= 1 (got {args.episodes}, {args.workers}): the "
                              "map's random exploration needs episodes, and 400 is the measured map's")
        if args.cmd == "map" and anatomy_set(args.anatomy) is not None:
            benchmark_maps(args.anatomy, args.episodes, args.seed, args.workers, args.version)
            return
        if args.cmd == "map":
            meta = make_map(args.episodes, args.seed, anatomy_id=args.anatomy, workers=args.workers,
                            version=args.version)
            args.out = args.out or (targets_file(args.version) if args.anatomy is None
                                    else map_path(anatomy.stomach_dir(args.anatomy), args.version))
        else:
            args.out = args.out or targets_file(args.version)
            meta = redraw(read_map(args.out) if args.out.exists() else load_error(args.out), args.seed, args.version)
        write_map(meta, args.out)
        print(json.dumps(meta["info"], indent=1))
        print(f"wrote {args.out}: lists " + ", ".join(f"{k} {len(v)}" for k, v in meta["lists"].items()))

    return cli.run(command, ConfigError)


if __name__ == "__main__":
    raise SystemExit(main())
