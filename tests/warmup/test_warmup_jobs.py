"""Each subsystem registers its own warm-up jobs; the warm-up gathers every one.

A module that defines ``WARMUP_JOBS`` (a package's ``warmup_jobs.py``, or a flat
module such as ``service/lookingglass.py``) is found by reading the sources, so a
new subsystem whose jobs are not in :data:`service.warmup.JOB_MODULES` fails here
instead of leaving its kernels to compile in a user's first frames.
"""

from __future__ import annotations

import ast
import queue
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


def test_a_job_that_runs_after_another_names_an_earlier_shared_job():
    names = list(warmup.JOBS)
    chained = {n: j.after for n, j in warmup.JOBS.items() if j.after}
    assert chained, "no job declares the job it follows"
    for name, after in chained.items():
        assert warmup.JOBS[name].part == HERE and warmup.JOBS[after].part == HERE, name
        assert names.index(after) < names.index(name), name


def test_a_job_is_claimed_by_the_first_process_to_ask(tmp_path):
    import subprocess
    import sys

    name = next(n for n, j in warmup.JOBS.items() if j.part == HERE)
    ask = ("import sys; from pathlib import Path; from service.warmup import claim; "
           "print(claim(Path(sys.argv[1]), sys.argv[2]))")
    first = subprocess.run([sys.executable, "-c", ask, str(tmp_path), name], cwd=ROOT,
                           capture_output=True, text=True, check=True)
    assert first.stdout.strip() == "True"
    assert warmup.claim(tmp_path, name) is False  # the other process has it
    (held,) = tmp_path.iterdir()
    assert held.read_text().strip().isdigit()  # the claimer's pid


def test_shared_jobs_run_where_claimed_and_a_chain_goes_together(tmp_path, monkeypatch):
    """Claims the other process holds are skipped, with every job ``after`` them."""
    ran: list[str] = []

    def job(name: str, after: str = "") -> Job:
        return Job(lambda kit: ran.append(name), HERE, after=after)

    jobs = {"a": job("a"), "b": job("b"), "b2": job("b2", after="b"), "c": job("c"),
            "b3": job("b3", after="b2"), "d": job("d", after="c")}
    monkeypatch.setattr(warmup, "JOBS", jobs)
    names = list(jobs)
    # the other process claimed "b" (so its chain b2, b3 too) before this one asks
    (tmp_path / f"{names.index('b')}.claim").write_text("1")
    report = warmup._Progress(len(names), None)
    here = warmup._run_here(names, warmup.Kit(), report, True, None, tmp_path)
    assert here == ran == ["a", "c", "d"]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        f"{names.index(n)}.claim" for n in ("a", "b", "c"))
    # without a shared folder (one process) every job runs, in order
    ran.clear()
    assert warmup._run_here(names, warmup.Kit(), report, False, None, None) == names == ran


def test_the_childs_jobs_load_here_as_it_finishes_them(monkeypatch):
    """Each job the child reports runs here at once (loaded), before the child ends.

    The child reports "a", and reports "b" only once "a" has run here; "c" it never
    reports (it failed), so it runs here and is reported from here; "d" ran here.
    """
    ran: list[str] = []
    finished: queue.Queue = queue.Queue()

    def job(name: str) -> Job:
        def run(kit) -> None:
            ran.append(name)
            if name == "a":  # the child goes on only once this process loaded "a"
                finished.put("b")
                finished.put(None)

        return Job(run, HERE)

    jobs = {n: job(n) for n in ("first", "a", "b", "c", "d")}
    jobs["first"] = Job(lambda kit: ran.append("first"), FIRST)
    monkeypatch.setattr(warmup, "JOBS", jobs)
    names = list(jobs)
    report = warmup._Progress(len(names), None)
    finished.put("a")
    warmup._check_child(names, warmup.Kit(), report, ["d"], finished)
    assert ran == ["a", "b", "c"]
    assert [s.name for s in report.steps] == ["c"]


def test_the_collector_runs_less_often_while_compiling_and_is_put_back():
    import gc

    from service.warmup import COMPILE_GC_THRESHOLD, fewer_collections

    before = gc.get_threshold()
    with pytest.raises(KeyError), fewer_collections():
        assert gc.get_threshold() == COMPILE_GC_THRESHOLD
        assert gc.get_freeze_count() > 1000  # the modules alive on entry: never scanned
        raise KeyError("a job failed")
    assert gc.get_threshold() == before
    assert gc.get_freeze_count() == 0
