"""How close the fast stomach is to the full FEM one: the protocols behind the fidelity figures.

Three measurements, each defined once here and used by ``make bench --only
fidelity``, the calibration (``python -m mjendo.fidelity calibrate``) and the
tests:

* **target motion**: peak-to-peak displacement (mm) of every target vertex
  (lists A and B) over one load cycle, after one cycle of settling, with the
  scope withdrawn; what a moving target does to the task;
* **press force**: the resultant contact force (N) on the scope, averaged over
  the last 0.5 s of a 1 s hold, for fixed commanded presses in the static
  stomach: end-on into the greater curvature, and the bent tip driven into
  a side wall by insertion (``PRESSES``);
* **hold speed**: tip and wall-vertex speeds (mm/s) while a press is held:
  a damped elastic system under constant load must come to rest.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from mjendo import anatomy, scene
from mjendo.config import FIDELITIES, Fidelity
from mjendo.sim import Simulator
from mjendo.units import from_mm, to_mm


@dataclass(frozen=True)
class Press:
    """A commanded press: bend first (cable pull), then insert to a fixed depth, hold."""

    name: str
    insertion_mm: float  # commanded insertion after the bend
    cable: int | None = None  # which cable is pulled (None: straight scope)
    pull_mm: float = 8.0  # ~80 degrees of bend
    pre_insertion_mm: float = 0.0  # insertion while bending, before the press


# Straight insertion first touches the greater curvature at about 125 mm;
# the bent presses bend at 80 mm and then push the bent tip 40 mm further.
PRESSES = (
    Press("end-on 140 mm", 140.0),
    Press("end-on 155 mm", 155.0),
    Press("bent +x, 80->120 mm", 120.0, cable=0, pre_insertion_mm=80.0),
    Press("bent +y, 80->120 mm", 120.0, cable=2, pre_insertion_mm=80.0),
    Press("bent -y, 80->120 mm", 120.0, cable=3, pre_insertion_mm=80.0),
)
HOLD_S = 1.0


def simulator(env: str, fidelity: str | Fidelity) -> Simulator:
    """A Simulator on the committed scene, or on a variant preset built in a temporary file."""
    if isinstance(fidelity, str):
        return Simulator(env, fidelity)
    base = "full" if fidelity.dof == "full" else "fast"
    path = Path(tempfile.mkdtemp(prefix="mjendo-")) / f"{env}_{fidelity.name}.xml"
    path.write_text(scene.scene_xml(env, fidelity))
    return Simulator(env, base, path=path)


def _run(sim: Simulator, seconds: float, pulls: np.ndarray, insertion: float) -> None:
    sim.set_controls(pulls, insertion)
    sim.step(int(round(seconds / sim.model.opt.timestep)))


def _ramp(sim: Simulator, seconds: float, pulls0, pulls1, ins0: float, ins1: float) -> None:
    n = int(round(seconds / sim.model.opt.timestep))
    for k in range(1, n + 1):
        f = k / n
        sim.set_controls(pulls0 + f * (pulls1 - pulls0), ins0 + f * (ins1 - ins0))
        sim.step(1)


def press(sim: Simulator, p: Press) -> None:
    """Settle 0.5 s, bend and pre-insert over 0.5 s, insert to the press depth over 0.5 s."""
    sim.reset()
    zero = np.zeros(4)
    _run(sim, 0.5, zero, 0.0)
    pulls = zero.copy()
    if p.cable is not None:
        pulls[p.cable] = from_mm(p.pull_mm)
    _ramp(sim, 0.5, zero, pulls, 0.0, from_mm(p.pre_insertion_mm))
    _ramp(sim, 0.5, pulls, pulls, from_mm(p.pre_insertion_mm), from_mm(p.insertion_mm))


def press_force(sim: Simulator, p: Press, hold_s: float = HOLD_S) -> float:
    """Mean resultant contact force (N) over the last 0.5 s of the hold."""
    press(sim, p)
    dt = sim.model.opt.timestep
    sim.step(int(round((hold_s - 0.5) / dt)))
    forces = []
    for _ in range(int(round(0.5 / dt))):
        sim.step(1)
        forces.append(float(np.linalg.norm(sim.contact().force)))
    return float(np.mean(forces))


def hold_speeds(sim: Simulator, p: Press, hold_s: float = 2.0, window_s: float = 0.5) -> tuple[float, float]:
    """Tip speed and fastest wall-vertex speed (mm/s), averaged over a window after ``hold_s`` of hold.

    Averaging displacement over a window measures drift and chatter alike,
    and not the single-step jitter of a converged solve.
    """
    press(sim, p)
    dt = sim.model.opt.timestep
    sim.step(int(round(hold_s / dt)))
    tip0, wall0 = sim.tip_pos(), sim.vertices()
    sim.step(int(round(window_s / dt)))
    tip = to_mm(np.linalg.norm(sim.tip_pos() - tip0)) / window_s
    wall = to_mm(np.linalg.norm(sim.vertices() - wall0, axis=1).max()) / window_s
    return float(tip), float(wall)


def target_motion(sim: Simulator, targets: list[int]) -> np.ndarray:
    """Peak-to-peak displacement (mm) of each target over the second load cycle, scope withdrawn."""
    sim.reset()
    sim.set_controls(np.zeros(4), sim.insertion_range[0])
    cycle = 2 * sim.half_period
    sim.step(int(round(cycle / sim.model.opt.timestep)))
    lo = hi = sim.vertices(targets)
    for _ in range(int(round(cycle / sim.model.opt.timestep))):
        sim.step(1)
        x = sim.vertices(targets)
        lo, hi = np.minimum(lo, x), np.maximum(hi, x)
    return to_mm(np.linalg.norm(hi - lo, axis=1))


def all_targets() -> list[int]:
    st = anatomy.load()
    return sorted(st.targets_a + st.targets_b)


def motion_summary(env: str, fidelity: str | Fidelity) -> dict:
    p2p = target_motion(simulator(env, fidelity), all_targets())
    return {"median_mm": float(np.median(p2p)), "max_mm": float(np.max(p2p))}


def force_summary(fidelity: str | Fidelity) -> dict[str, float]:
    sim = simulator("SE", fidelity)
    return {p.name: press_force(sim, p) for p in PRESSES}


def compare(candidate: str | Fidelity, reference: str = "full") -> dict:
    """Ratios candidate / reference for every fidelity figure (target motion median, max; press forces)."""
    out = {}
    for env in ("DE", "UE1", "UE2"):
        a, b = motion_summary(env, candidate), motion_summary(env, reference)
        out[f"{env} motion median"] = a["median_mm"] / b["median_mm"]
        out[f"{env} motion max"] = a["max_mm"] / b["max_mm"]
    fa, fb = force_summary(candidate), force_summary(reference)
    for k in fa:
        out[f"force {k}"] = fa[k] / fb[k] if fb[k] > 0 else float("nan")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m mjendo.fidelity", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cells", type=int, nargs=3, help="trilinear cell counts of a candidate fast stomach")
    ap.add_argument("--young-scale", type=float, help="young's modulus factor of the candidate")
    args = ap.parse_args(argv)
    fid = FIDELITIES["fast"]
    if args.cells:
        fid = replace(fid, name="candidate", cellcount=tuple(args.cells))
    if args.young_scale:
        fid = replace(fid, name="candidate", young_scale=args.young_scale)
    ratios = compare(fid)
    for k, v in ratios.items():
        print(f"{k:<40}{v:8.2f}")
    print(f"median |log ratio|: {statistics.median(abs(np.log(v)) for v in ratios.values()):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
