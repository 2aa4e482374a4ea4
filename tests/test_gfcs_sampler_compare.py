"""experiments/gfcs_sampler_compare.py: per-class rows and the mean a shared setting is chosen on."""

import json
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parent.parent / "experiments" / "gfcs_sampler_compare.py"
sys.path.insert(0, str(SCRIPT.parent))
import gfcs_sampler_compare as cmp  # noqa: E402


def _write(path: Path, cls: str, uniform_ee: float, learned_ee: float, success: float = 100.0) -> None:
    def row(ee, s, dist):
        return {"n": 10, "success_pct": s, "ee_length": ee, "distance_median": dist, "ee_change_pct": 100.0 * (ee / uniform_ee - 1.0)}

    table = {"uniform": row(uniform_ee, 100.0, 1.0), "learned": row(learned_ee, success, 0.5)}
    path.write_text(json.dumps({"class": cls, "split": "train", "problems": ["x"], "run": str(path.parent), "table": table}))


def test_rows_per_class_and_mean_over_shared_classes(tmp_path):
    for s, ees in (("a", (1.8, 0.9)), ("b", (1.5, 1.0))):
        (tmp_path / s).mkdir()
        _write(tmp_path / s / "tu.json", "table_under_pick", 2.0, ees[0])
        _write(tmp_path / s / "box.json", "box", 1.0, ees[1], success=90.0 if s == "a" else 100.0)
    _write(tmp_path / "b" / "cage.json", "cage", 1.0, 0.5)  # only in b: shown, not in the mean
    cmp.main([f"x01={tmp_path}/a/tu.json,{tmp_path}/a/box.json", f"x1={tmp_path}/b/*.json", "--out", str(tmp_path / "out")])
    result = json.loads((tmp_path / "out.json").read_text())
    assert result["mean_over"] == ["box", "table_under_pick"]
    assert result["mean"]["x01"]["ee_change_pct"] == pytest.approx((-10.0 - 10.0) / 2)
    assert result["mean"]["x1"]["ee_change_pct"] == pytest.approx((-25.0 + 0.0) / 2)
    assert result["mean"]["x01"]["success_pct"] == pytest.approx(95.0)
    assert "x01" not in result["classes"]["cage"] and result["classes"]["cage"]["x1"]["ee_length"] == 0.5
    md = (tmp_path / "out.md").read_text()
    assert "| cage | 100, 1.00 | – | 100, 0.50, -50 %, 0.50 |" in md


def test_refuses_bad_settings(tmp_path):
    with pytest.raises(SystemExit, match="no file matches"):
        cmp.main([f"a={tmp_path}/none*.json", "--out", str(tmp_path / "o")])
    for text in ("{}", "[1, 2]", "not json"):
        (tmp_path / "bad.json").write_text(text)
        with pytest.raises(SystemExit, match="not a gfcs_sampler.py output"):
            cmp.main([f"a={tmp_path}/bad.json", "--out", str(tmp_path / "o")])
    _write(tmp_path / "box1.json", "box", 1.0, 0.9)
    _write(tmp_path / "box2.json", "box", 1.0, 0.8)
    with pytest.raises(SystemExit, match="a second file for class box"):
        cmp.main([f"a={tmp_path}/box1.json,{tmp_path}/box2.json", "--out", str(tmp_path / "o")])
    with pytest.raises(SystemExit, match="LABEL=GLOB"):
        cmp.main(["nolabel", "--out", str(tmp_path / "o")])
