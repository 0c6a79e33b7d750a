"""python -m mjendo.compare: two policies' seeds read back from evaluation reports, with the study's intervals."""

import numpy as np
import pytest

from mjendo import compare
from mjendo.config import ConfigError
from mjendo.evaluation import write_table


def trials(controller: str, rate: float, n: int = 40, env: str = "DE") -> list[dict]:
    """n trials over 10 targets, the first rate * n of them successful."""
    return [{"controller": controller, "env": env, "trial": i, "target": 100 + i % 10, "anatomy": "",
             "success": str(i < rate * n), "error": ""} for i in range(n)]


@pytest.fixture
def reports(tmp_path):
    """Two draws of E (three seeds, about 85 %) and D (three seeds, about 60 %) in separate report folders."""
    for draw in (1, 2):
        for pol, rates in (("E", (0.85, 0.8, 0.9)), ("D", (0.6, 0.55, 0.65))):
            folder = tmp_path / f"{pol}{draw}"
            folder.mkdir()
            rows = [r for s, rate in enumerate(rates) for r in trials(f"runs/{pol}/x-seed{s}", rate)]
            rows += trials("runs/E/x-seed0", 0.0, env="UE2")  # another environment: not counted
            write_table(folder / "trials.csv.gz", rows)
    return sorted(tmp_path.iterdir())


def test_pools_each_seed_over_the_reports_and_the_difference_has_the_right_sign(reports):
    res = compare.compare(reports, "runs/E/", "runs/D/", "DE")
    assert res["a"]["seeds"] == 3 and res["a"]["trials"] == [80, 80, 80]
    assert np.allclose(res["a"]["per_seed"], [0.85, 0.8, 0.9]) and np.isclose(res["a"]["mean"], 0.85)
    assert np.isclose(res["b"]["mean"], 0.6)
    d = res["a - b"]
    assert np.isclose(d["mean"], 0.25)
    assert 0 < d["low"] < 0.25 < d["high"] and 0 < d["low_targets"] < 0.25 < d["high_targets"]
    assert d["excludes_zero"]
    text = compare.report(res, "runs/E/", "runs/D/", "DE")
    assert "85.0" in text and "+25.0 points" in text


def test_bad_input_names_the_fix(reports, tmp_path, capsys):
    with pytest.raises(ConfigError, match="no controller in DE contains 'runs/C/'"):
        compare.compare(reports, "runs/E/", "runs/C/")
    with pytest.raises(ConfigError, match="match both"):
        compare.compare(reports, "runs/", "runs/E/")
    assert compare.main(["--a", "E", "--b", "D", str(tmp_path / "nowhere")]) == 2
    assert "no trials table at" in capsys.readouterr().err
