"""`springc bench --population`'s page records its ratio only at a load where the memory
traffic it measures still shows, and always says the load, the date and the CPU."""

from __future__ import annotations

from springc.bench.population import markdown, max_load

NUMBERS = {"masses": 500, "samples": 256, "tstop": 1.0, "tstep": 1e-3, "threads": 2,
           "nominal_s": 0.243, "population_s": 0.425, "ratio": 0.425 / 0.243, "calls": 1,
           "scipy_s": [2.9], "scipy_ratio": 1734.0, "springc_per_sample_s": 1.66e-3,
           "compile_nominal_s": 6.1, "compile_population_s": 6.4, "elaborate_check_s": 3.1,
           "scipy_vs_springc_rel": [1.3e-5], "when": "2026-11-28 20:29:00",
           "cpu": "AMD EPYC"}


def test_quiet_run_records_its_ratio() -> None:
    page = markdown({**NUMBERS, "load": 0.88})
    assert "**1.75x**" in page
    assert "AMD EPYC, 2 cores; measured 2026-11-28 20:29:00" in page


def test_paired_run_gives_its_median_ratio_and_range() -> None:
    walls = {"nominal": [0.33, 0.37, 0.43], "population": [0.47, 0.52, 0.55]}
    page = markdown({**NUMBERS, "load": 0.5, "ratio": 1.40, "ratio_range": [1.27, 1.42],
                     "walls": walls})
    assert "**1.40x** (median, 1.27-1.42 over 3 alternating pairs; target" in page


def test_loaded_run_says_why_it_records_no_ratio() -> None:
    load = max_load(2) + 0.01
    page = markdown({**NUMBERS, "load": load})
    assert "1.75x" not in page
    assert f"not recorded: load average {load:.2f} above {max_load(2):g}" in page
