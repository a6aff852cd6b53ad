"""Each subsystem registers its own warm-up jobs; the warm-up gathers every one.

A module that defines ``WARMUP_JOBS`` (a package's ``warmup_jobs.py``, or a flat
module such as ``service/lookingglass.py``) is found by reading the sources, so a
new subsystem whose jobs are not in :data:`service.warmup.JOB_MODULES` fails here
instead of leaving its kernels to compile in a user's first frames.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from service import warmup
from service.warmup_job import EARLY, FIRST, HERE, PARTS, Job

ROOT = Path(__file__).resolve().parents[2]


def _registering_modules() -> set[str]:
    found = set()
    for path in (ROOT / "service").rglob("*.py"):
        tree = ast.parse(path.read_text())
        for node in tree.body:
            target = getattr(node, "target", None) or (node.targets[0] if isinstance(
                node, ast.Assign) else None)
            if isinstance(target, ast.Name) and target.id == "WARMUP_JOBS":
                rel = path.relative_to(ROOT).with_suffix("")
                found.add(".".join(rel.parts))
    return found


def test_every_module_that_registers_jobs_is_gathered():
    gathered = {m.__name__ for m in warmup.JOB_MODULES}
    assert _registering_modules() == gathered
    names = [n for m in warmup.JOB_MODULES for n in m.WARMUP_JOBS]
    assert sorted(warmup.JOBS) == sorted(names)


def test_jobs_run_part_by_part_in_their_modules_order():
    parts = [job.part for job in warmup.JOBS.values()]
    assert parts == sorted(parts, key=PARTS.index)
    assert set(warmup.FIRST_FRAME_JOBS) <= set(warmup.JOBS)
    assert set(warmup.SERVICE_JOBS) <= set(warmup.JOBS)


def test_a_job_name_registered_twice_is_refused():
    class A:
        WARMUP_JOBS = {"same": Job(lambda kit: None, FIRST)}

    class B:
        WARMUP_JOBS = {"other": Job(lambda kit: None, HERE), "same": Job(lambda kit: None, EARLY)}

    with pytest.raises(ValueError, match="'same' registered twice"):
        warmup._gather((A, B))
    assert list(warmup._gather((B,))) == ["same", "other"]  # EARLY before HERE
