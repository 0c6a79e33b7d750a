"""Verify target reachability in simulation and write the target lists A and B.

``anatomy.build`` proposes candidate targets geometrically (lumen vertices
near the free-space workspace). This module keeps only candidates the
endoscope actually gets close to in the static stomach, by seeded random
exploration with contact (``python -m mjendo.targets``), then splits them
into list A (training, 2/3) and list B (held out, 1/3), interleaved around
the insertion axis so both cover the same regions.
"""

from __future__ import annotations

import argparse

import numpy as np

from mjendo import anatomy
from mjendo.units import to_mm

REACH_MM = 6.0  # a candidate is kept when exploration brought the tip this close
EPISODES = 400
STEPS = 128
# The exploration's own step sizes (those that produced the committed lists):
# tuning the policies' action scale must not move the targets.
EXPLORE_SCALES = {"cable_mm_per_unit": 2.5, "insertion_mm_per_unit": 5.0}


def explore(episodes: int = EPISODES, seed: int = 0, fidelity: str = "fast", progress: bool = True) -> tuple:
    """Closest tip approach (mm) to every candidate over seeded random exploration in SE."""
    from tqdm import tqdm

    from mjendo.task import NavigationTask

    st = anatomy.load()
    cand = np.array(sorted(set(st.info.get("candidates", st.targets_a + st.targets_b))))
    task = NavigationTask(env="SE", fidelity=fidelity, max_steps=STEPS, randomize_phase=False, **EXPLORE_SCALES)
    rng = np.random.default_rng(seed)
    best = np.full(len(cand), np.inf)
    for ep in tqdm(range(episodes), desc="exploring", disable=not progress):
        task.reset(np.random.default_rng(seed + ep))
        a = np.zeros(5)
        for k in range(STEPS):
            if k % 8 == 0:  # piecewise-constant actions explore further than white noise
                a = rng.uniform(-0.4, 0.4, 5)
                a[4] = rng.uniform(-0.1, 0.4)
            res = task.step(a)
            d = to_mm(np.linalg.norm(task.sim.vertices(cand) - task.sim.tip_pos(), axis=1))
            best = np.minimum(best, d)
            if res.terminated and res.info["exited"]:
                break
    return cand, best


def split(cand: np.ndarray, best: np.ndarray, st: anatomy.Stomach) -> tuple[list[int], list[int]]:
    """Lists A and B of the candidates exploration reached (anatomy's split rule)."""
    return anatomy.split_targets(st.mesh.points, st.entry, st.axis, cand[best < REACH_MM])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m mjendo.targets", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--episodes", type=int, default=EPISODES)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    st = anatomy.load()
    cand, best = explore(args.episodes, args.seed)
    a, b = split(cand, best, st)
    st.info["candidates"] = cand.tolist()
    st.info["candidate_reach_mm"] = [round(float(x), 2) for x in best]
    st.info["target_rule"] = (f"candidates approached within {REACH_MM} mm by {args.episodes} seeded random "
                              f"exploration episodes in SE (seed {args.seed}): python -m mjendo.targets")
    st.targets_a, st.targets_b = a, b
    anatomy.save(st)
    print(f"{len(cand)} candidates, {len(a) + len(b)} reachable: list A {len(a)}, list B {len(b)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
