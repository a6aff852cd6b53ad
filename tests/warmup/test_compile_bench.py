"""``holo-bench compile``: cold compile seconds per warm-up job and kernel, and the report's table.

One real cold compile of one small job (mesh repair, about 9 s of CPU) in a child
with a temporary numba cache; the session's own cache files of its kernels must not
change.
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest
from testkit import HANG_S

from service.bench import report
from service.warmup import cache_files

ROOT = Path(__file__).resolve().parents[2]
JOB = "mesh files: repair"


@pytest.mark.timeout(300)
def test_compile_times_a_job_and_its_kernels_from_an_empty_cache(tmp_path):
    before = cache_files()
    out = tmp_path / "compile"
    proc = subprocess.run([sys.executable, "-m", "service.commands.holo_bench", "compile", "--job",
                           JOB,
                           "--out", str(out)], cwd=ROOT, capture_output=True, text=True,
                          timeout=280, check=False)
    assert proc.returncode == 0, proc.stderr
    assert JOB in proc.stdout and "CPU" in proc.stdout
    with (out / "compile_jobs.csv").open() as fh:
        (job,) = list(csv.DictReader(fh))
    assert job["job"] == JOB and int(job["kernels"]) >= 3 and float(job["cpu_s"]) > 0
    assert job["first_frame"] == "False"  # compiled in a cold service's background phase
    with (out / "compile_kernels.csv").open() as fh:
        kernels = list(csv.DictReader(fh))
    names = {k["kernel"] for k in kernels}
    assert "service.triangulate_kernel.ear_clip_polygons" in names, names
    assert all(k["kernel"].startswith("service.") for k in kernels)  # numba's own folded in
    assert all(float(k["cpu_s"]) >= 0 for k in kernels)
    # the costliest first; each kernel's own seconds sum to no more than the job's CPU
    cpu = [float(k["cpu_s"]) for k in kernels]
    assert cpu == sorted(cpu, reverse=True)
    assert sum(cpu) <= float(job["cpu_s"]) + 0.5
    data = json.loads((out / "compile.json").read_text())
    assert data["whole"] is None and data["budget"] == {"whole_wall_s": 60.0, "job_wall_s": 15.0}
    assert data["first_frame_cpu_s"] == 0
    assert (out / "compile.png").stat().st_size > 1000
    # the user's cache untouched: the files of the job's kernels (other test processes
    # may add test-only kernels to it meanwhile)
    mine = _files_of(before, names)
    assert mine and _files_of(cache_files(), names) == mine


def _files_of(files: dict, kernels: set) -> dict:
    """The cache files (``cache_files()``) of the kernels named ``module.function``."""
    stems = tuple(f".{name.rsplit('.', 1)[-1]}-" for name in kernels)
    return {p: v for p, v in files.items() if any(s in Path(p).name for s in stems)}


def test_the_report_table_lists_jobs_the_whole_warmup_and_the_budget(tmp_path):
    data = {"jobs": [{"job": "render zbuffer", "wall_s": 9.5, "cpu_s": 12.25, "kernels": 20},
                     {"job": "galilean", "wall_s": 40.0, "cpu_s": 55.0, "kernels": 9}],
            "whole": {"wall_s": 75.0, "cpu_s": 130.0}, "load": [1.2, 1.5], "cores": 2,
            "budget": {"whole_wall_s": 60.0, "job_wall_s": 15.0}, "over_budget": ["galilean"]}
    (tmp_path / "compile.json").write_text(json.dumps(data))
    table = report.compile_table(tmp_path)
    assert table.headers == ["job", "wall s", "CPU s", "kernels", "budget"]
    assert table.rows[0] == ["render zbuffer", "9.500", "12.250", "20", "within"]
    assert table.rows[1][-1] == "over"
    assert table.rows[2][0].startswith("whole holo-warmup") and table.rows[2][-1] == "over"
    assert "load 1.2-1.5 on 2 cores" in table.note


def test_a_bad_job_name_is_a_usage_error():
    proc = subprocess.run([sys.executable, "-m", "service.commands.holo_bench", "compile", "--job",
                           "no such job", "--out", "/tmp/x"], cwd=ROOT, capture_output=True,
                          text=True, timeout=HANG_S * 6, check=False)
    assert proc.returncode == 2 and "invalid choice" in proc.stderr
    assert "Traceback" not in proc.stderr
