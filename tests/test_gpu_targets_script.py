"""scripts/gpu_targets.py on the stored GPU runs (docs/bench/gpu/, written by
`scripts/gpu_check.sh`): it reads back the figures docs/bench-gpu.md gives for issue 41's
targets, and says missing where a stage left nothing."""

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "gpu_targets.py"
RUNS = ROOT / "docs" / "bench" / "gpu"


def _lines(folder: str, capsys) -> list[str]:
    spec = importlib.util.spec_from_file_location("gpu_targets", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.main([str(RUNS / folder)]) == 0
    return capsys.readouterr().out.splitlines()


def test_the_h100_runs_read_back_as_the_page_gives_them(capsys):
    first = _lines("2026-11-26", capsys)
    assert ("agreement (fused, float32): MISSED, worst 1.94e-04 (stiff block) against 1e-05, "
            "5 networks") in first
    assert "agreement (no fma): missing (compare_no_fma.json)" in first
    later = _lines("2026-11-27", capsys)
    assert ("agreement (fused, float64): MET, worst 1.05e-13 (pipeline classifier 8x3) "
            "against 1e-12, 4 networks") in later
    assert ("50x the 2-core CPU: MISSED, 6,528 (cuda_throughput.json) against 1,096 runs/s: "
            "6.0x") in later
    assert any(line.startswith("3x JAX, 564-dof kws network: MISSED, 1.67x") for line in later)


def test_the_h200_run_reads_back_as_the_page_gives_it(capsys):
    lines = _lines("2026-11-27-h200", capsys)
    assert any(line.startswith("3x JAX, pipeline features 8x3: MET, 4.21x") for line in lines)
    assert "3x JAX: missing (peers_kws.json)" in lines  # that stage ran out of its time
