"""Longer checks (pytest -m slow): the full-FEM stomach's load response and rest shape."""

import numpy as np
import pytest

from mjendo.sim import Simulator

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("env,scale", [("DE", 1.0), ("UE2", 3.0)])
def test_full_fem_wall_follows_the_load(stomach, env, scale):
    sim = Simulator(env, "full")
    sim.set_controls(np.zeros(4), sim.insertion_range[0])
    z = []
    while sim.time < 6.0:
        sim.step(1)
        z.append(sim.vertices(stomach.forced)[:, 2].mean())
    z = np.array(z)
    t = np.arange(1, len(z) + 1) * sim.model.opt.timestep
    at = {x: z[np.argmin(np.abs(t - x))] for x in (3.95, 5.95)}
    p2p_mm = (at[5.95] - at[3.95]) * 1e3
    assert 2.0 * scale < p2p_mm < 15.0 * scale


def test_full_and_fast_settle_to_the_same_stomach(stomach):
    # Same anchors, same load-free rest shape: held by its anchors and the organs around it, each
    # fidelity sags 1-3 mm under gravity (measured 1.7 and 1.8 mm), and their settled walls agree
    # within 2.5 mm.
    settled, sag = {}, {}
    for fid in ("fast", "full"):
        sim = Simulator("SE", fid)
        x0 = sim.vertices()
        sim.set_controls(np.zeros(4), sim.insertion_range[0])
        sim.step(300)
        settled[fid] = sim.vertices()
        sag[fid] = np.linalg.norm(settled[fid] - x0, axis=1).max() * 1e3
        assert np.abs(settled[fid][stomach.fixed] - x0[stomach.fixed]).max() < 1e-3
    assert all(1.0 < s < 3.0 for s in sag.values()), sag
    apart = np.linalg.norm(settled["fast"] - settled["full"], axis=1) * 1e3
    assert apart.max() < 2.5 and np.median(apart) < 1.0


@pytest.fixture(scope="module")
def fast_over_full():
    from mjendo import fidelity

    return fidelity.compare("fast", "full")


def test_fast_stomach_is_calibrated_to_the_full_one(fast_over_full):
    # The calibration's bars (docs/physics.md): median target motion within +-25 % of the full stomach's
    # (the load gains are set to match it), press forces within a factor 1.5 either way.
    for name, r in fast_over_full.items():
        if name.endswith("motion max"):
            continue
        lo, hi = (1 / 1.5, 1.5) if name.startswith("force") else (0.75, 1.25)
        assert lo <= r <= hi, f"{name}: fast/full = {r:.2f}"


@pytest.mark.xfail(strict=True, reason="known limit (docs/physics.md, version 1): the 27-node stomach moves as a "
                   "whole where the FEM one deforms locally, so its largest target motions exceed the full one's")
def test_fast_stomachs_largest_target_motion_matches_the_full_ones(fast_over_full):
    for env in ("DE", "UE1", "UE2"):
        r = fast_over_full[f"{env} motion max"]
        assert 0.75 <= r <= 1.25, f"{env} motion max: fast/full = {r:.2f}"
