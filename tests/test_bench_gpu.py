"""experiments/bench_gpu.py on the CPU: its sections write rows, and the wall budget stops a section."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parent.parent / "experiments" / "bench_gpu.py"


def _run(tmp_path: Path, *args: str, timeout: float = 600) -> tuple[int, dict, str]:
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, str(SCRIPT), "--sizes", "cpu", "--out", str(out), *args], capture_output=True, text=True, timeout=timeout)
    results = json.loads((out / "results.json").read_text()) if (out / "results.json").exists() else {}
    return proc.returncode, results, proc.stdout + proc.stderr


@pytest.mark.slow
def test_sections_measure_every_size_with_compile_apart(tmp_path):
    rc, results, log = _run(tmp_path, "--sections", "fabric,geodesics", "--budget", "400")
    assert rc == 0, log[-2000:]
    by = {s["section"]: s for s in results["sections"]}
    assert by["fabric"]["status"] == "ok" and by["geodesics"]["status"] == "ok", log[-2000:]
    assert [r["size"] for r in by["fabric"]["rows"]] == [1, 64]
    for s in by.values():
        for r in s["rows"]:
            assert r["rate"] > 0 and r["compile_s"] >= 0
    # 64 arms in one vmap step faster per arm than one arm alone
    one, many = by["fabric"]["rows"]
    assert many["rate"] > one["rate"]
    assert results["meta"]["backend"] == "cpu" and results["meta"]["sizes"] == "cpu"
    md = (tmp_path / "out" / "summary.md").read_text()
    assert "| fabric | 64 |" in md and "| geodesics | 32 |" in md


def test_a_section_past_its_slice_is_stopped_and_reported(tmp_path):
    """PPO cannot start in 15 s: its process is killed at the budget, the run still writes its report."""
    rc, results, log = _run(tmp_path, "--sections", "ppo", "--budget", "15", timeout=200)
    assert rc == 0, log[-2000:]
    (ppo,) = results["sections"]
    assert ppo["status"].startswith("timed out") or ppo["status"].startswith("skipped"), ppo
    assert ppo["rows"] == []
    assert "timed out" in (tmp_path / "out" / "summary.md").read_text() or "skipped" in (tmp_path / "out" / "summary.md").read_text()


def test_bad_arguments_fail_before_any_work(tmp_path):
    rc, _, log = _run(tmp_path, "--sections", "fabric,warp", "--budget", "10", timeout=60)
    assert rc != 0 and "unknown sections ['warp']" in log and "Traceback" not in log
    rc, _, log = _run(tmp_path, "--budget", "0", timeout=60)
    assert rc != 0 and "--budget must be positive" in log


def test_slices_share_the_remaining_budget_by_weight():
    sys.path.insert(0, str(SCRIPT.parent))
    import bench_gpu

    sections = list(bench_gpu.SECTIONS)
    total = sum(bench_gpu.WEIGHTS[s] for s in sections)
    assert bench_gpu.slices(100.0, sections) == pytest.approx(100.0 * bench_gpu.WEIGHTS["fabric"] / total)
    assert bench_gpu.slices(50.0, ["geodesics"]) == pytest.approx(50.0)
