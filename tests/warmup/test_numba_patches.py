"""service.numba_patches: numba's copy propagation, the same result at less cost."""

from __future__ import annotations

import re

import numba as nb
import numpy as np
import pytest
from numba.core import ir_utils
from numba.parfors import parfor

from service import numba_patches


def _parallel_source():
    """A fresh (uncached) parallel function with copies, branches and a loop in its prange."""

    def f(a, b, n):
        for i in nb.prange(a.shape[0]):
            x = a[i]
            y = x
            s = 0.0
            for k in range(n):
                if y > k:
                    s += y - k
                else:
                    z = s
                    s = z * 0.5
            b[i] = s
        return b

    return nb.njit(parallel=True, cache=False)(f)


@pytest.fixture
def numba_original(monkeypatch):
    """numba's own copy_propagate, put back in place for the test (and restored after).

    A warm-up earlier in this process (a service's readiness, say) may have
    swapped ours in already: numba's is then the one ours wraps.
    """
    original = ir_utils.copy_propagate
    original = getattr(original, "__wrapped__", original)
    monkeypatch.setattr(ir_utils, "copy_propagate", original)
    if numba_patches._source_digest(original) != numba_patches.COPY_PROPAGATE_SHA256:
        pytest.skip(f"numba {nb.__version__}'s copy_propagate is not the one the patch "
                    "reproduces: it is left alone")
    monkeypatch.setattr(parfor, "copy_propagate", original)
    return original


def test_same_copies_as_numba_on_a_real_parallel_compile(numba_original, monkeypatch):
    """Every call numba makes while compiling a prange: ours gives its exact result."""
    calls = []

    def both(blocks, typemap):
        theirs = numba_original(blocks, typemap)
        ours = numba_patches.copy_propagate(blocks, typemap)
        calls.append((theirs, ours))
        return theirs

    monkeypatch.setattr(parfor, "copy_propagate", both)
    f = _parallel_source()
    a = np.arange(6, dtype=np.float64)
    out = f(a, np.empty_like(a), 4)
    assert np.isfinite(out).all()
    assert calls, "the parallel compile did not propagate copies"
    found = 0
    for theirs, ours in calls:
        assert ours == theirs  # (in_copies, out_copies): label -> set of (lhs, rhs)
        found += sum(len(s) for s in theirs[1].values())
    assert found > 0  # copies were found, so the comparison compared something


def test_patch_is_applied_once_and_compiles_the_same(numba_original):
    """Applied, numba's parallel passes call ours; a kernel compiled so computes the same."""
    reference = _parallel_source()
    a = np.linspace(-2.0, 5.0, 11)
    want = reference(a, np.empty_like(a), 5)
    assert numba_patches.faster_copy_propagation() is True
    assert parfor.copy_propagate is numba_patches.copy_propagate
    assert numba_patches.copy_propagate.__wrapped__ is numba_original
    assert numba_patches.faster_copy_propagation() is True  # idempotent
    patched = _parallel_source()
    np.testing.assert_array_equal(patched(a, np.empty_like(a), 5), want)


def test_leaves_another_numba_alone(numba_original, monkeypatch):
    """A copy_propagate whose source differs from the one reproduced is not replaced."""
    monkeypatch.setattr(numba_patches, "COPY_PROPAGATE_SHA256", "0" * 64)
    assert numba_patches.faster_copy_propagation() is False
    assert parfor.copy_propagate is numba_original


def _inlining_source():
    """A fresh parallel kernel whose prange inlines a body with a loop and a branch twice."""

    @nb.njit(inline="always")
    def body(a, i, n):
        s = 0.0
        for k in range(n):
            if a[i] > k:
                s += a[i] - k
            else:
                t = s
                s = t * 0.5
        return s

    def f(a, b, n):
        for i in nb.prange(a.shape[0]):
            b[i] = body(a, i, n) + body(a, i, n + 1)
        return b

    return nb.njit(parallel=True, cache=False)(f)


def _same_names(asm: str) -> str:
    """Machine code without what differs between two compiles of one source.

    Each compile numbers its function (``...B2v17B...``; its name's length, in string
    sizes, with it) and names its gufunc after an address (``0x7f...``): the lines
    that name a symbol are left out, every instruction of the bodies stays.
    """
    return "\n".join(line for line in asm.splitlines() if "_ZN" not in line and "0x" not in line)


def _numbas_own(monkeypatch, owner: object, name: str, digest: str | None = None):
    """numba's own ``owner.name`` put back in place for the test (restored after).

    A warm-up earlier in this process may have patched it: numba's is the one the
    patch wraps (``__wrapped__``).  With ``digest``, the test is skipped where numba's
    source is not the one the patch was written against.
    """
    current = getattr(owner, name)
    original = getattr(current, "__wrapped__", current)
    monkeypatch.setattr(owner, name, original)
    if digest is not None and numba_patches._source_digest(original) != digest:
        pytest.skip(f"numba {nb.__version__}'s {owner.__name__}.{name} is not the one patched")
    return original


@pytest.fixture
def inline_original(monkeypatch):
    """numba's own ``InlineWorker.inline_ir`` in place for the test (restored after)."""
    from numba.core.inline_closurecall import InlineWorker

    return _numbas_own(monkeypatch, InlineWorker, "inline_ir", numba_patches.INLINE_IR_SHA256)


def test_inlining_with_one_memo_makes_the_same_machine_code(inline_original):
    from numba.core.inline_closurecall import InlineWorker

    a = np.linspace(-2.0, 5.0, 11)
    theirs = _inlining_source()
    want = theirs(a, np.empty_like(a), 5)
    assert numba_patches.faster_inlining() is True
    assert InlineWorker.inline_ir.__wrapped__ is inline_original
    assert numba_patches.faster_inlining() is True  # idempotent
    ours = _inlining_source()
    np.testing.assert_array_equal(ours(a, np.empty_like(a), 5), want)
    asm = [k.inspect_asm(k.signatures[0]) for k in (theirs, ours)]
    assert "gufunc" in asm[0]  # the parallel loop's body is in it
    body = _same_names(asm[0])
    assert body.count("\n") > 100 and body == _same_names(asm[1])


def test_inlining_leaves_another_numba_alone(inline_original, monkeypatch):
    from numba.core.inline_closurecall import InlineWorker

    monkeypatch.setattr(numba_patches, "INLINE_IR_SHA256", "0" * 64)
    assert numba_patches.faster_inlining() is False
    assert InlineWorker.inline_ir is inline_original


_SAVER = '''
import os, sys
sys.path.insert(0, sys.argv[1])
from service.numba_patches import locked_cache_saves
assert locked_cache_saves()
import kern
print(kern.f._cache._cache_path, flush=True)
sys.stdin.readline()
print(kern.f(20), flush=True)
'''


def _waiting_for_a_lock(pid: int) -> bool:
    """Whether ``pid`` waits for a file lock (``/proc/locks`` lists waiters with ``->``)."""
    try:
        lines = open("/proc/locks").read().splitlines()
    except OSError:
        return False
    return any("->" in line and f" {pid} " in f" {line} " for line in lines)


@pytest.mark.skipif(not __import__("os").path.exists("/proc/locks"), reason="needs /proc/locks")
@pytest.mark.timeout(120)
def test_a_cache_save_waits_while_another_process_holds_the_cache_lock(tmp_path):
    """The index and data of a new signature are written only under the folder's lock."""
    import fcntl
    import os
    import subprocess
    import sys
    from pathlib import Path

    from testkit import HANG_S, wait_until

    (tmp_path / "kern.py").write_text(
        "import numba\n\n@numba.njit(cache=True)\ndef f(n):\n    return n * (n + 1) // 2\n")
    root = Path(__file__).resolve().parents[2]
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"),
               PYTHONPATH=str(root))
    child = subprocess.Popen([sys.executable, "-c", _SAVER, str(tmp_path)], env=env,
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        cache = Path(child.stdout.readline().strip())
        cache.mkdir(parents=True, exist_ok=True)
        fd = os.open(cache / numba_patches.CACHE_LOCK, os.O_RDWR | os.O_CREAT)
        fcntl.flock(fd, fcntl.LOCK_EX)
        try:
            child.stdin.write("go\n")
            child.stdin.flush()
            # compiled, then blocked in the save: nothing of the kernel written yet
            assert wait_until(lambda: _waiting_for_a_lock(child.pid), 90), "never waited"
            assert not list(cache.glob("*.nb[ic]"))
        finally:
            os.close(fd)  # releases the lock
        assert child.stdout.readline().strip() == "210"
        assert child.wait(HANG_S) == 0
        assert len(list(cache.glob("*.nbi"))) == 1 and len(list(cache.glob("*.nbc"))) == 1
    finally:
        child.kill()
        child.wait()


@pytest.fixture
def values_original(monkeypatch):
    """numba's own ``TargetConfig.values`` in place for the test (restored after)."""
    from numba.core.targetconfig import TargetConfig

    return _numbas_own(monkeypatch, TargetConfig, "values", numba_patches.FLAG_VALUES_SHA256)


def _flag_sets():
    """Compiler flags as numba makes them: default, some options set, a copy, one unset again."""
    from numba.core.compiler import Flags

    plain = Flags()
    some = Flags()
    some.nrt = True
    some.error_model = "numpy"
    some.fastmath = True
    some.auto_parallel = True
    some.release_gil = False  # set to its default: still "set"
    copy = some.copy()
    copy.boundscheck = True
    unset = copy.copy()
    unset.discard("error_model")
    return [plain, some, copy, unset]


def test_flag_values_are_numbas_dict_key_for_key(values_original):
    for flags in _flag_sets():
        theirs = values_original(flags)
        ours = numba_patches.flag_values(flags)
        assert list(ours.items()) == list(theirs.items())  # same keys, order and values
        assert all(ours[k] is theirs[k] for k in theirs)  # the very objects
    a, b = _flag_sets()[1:3]
    assert (numba_patches.flag_values(a) == numba_patches.flag_values(b)) is False


def test_flag_values_patch_compiles_the_same(values_original):
    from numba.core.targetconfig import TargetConfig

    a = np.linspace(-2.0, 5.0, 11)
    theirs = _inlining_source()
    want = theirs(a, np.empty_like(a), 5)
    assert numba_patches.faster_flag_values() is True
    assert TargetConfig.values is numba_patches.flag_values
    assert numba_patches.flag_values.__wrapped__ is values_original
    assert numba_patches.faster_flag_values() is True  # idempotent
    ours = _inlining_source()
    np.testing.assert_array_equal(ours(a, np.empty_like(a), 5), want)
    asm = [k.inspect_asm(k.signatures[0]) for k in (theirs, ours)]
    assert _same_names(asm[0]) == _same_names(asm[1])


def test_flag_values_leave_another_numba_alone(values_original, monkeypatch):
    from numba.core.targetconfig import TargetConfig

    monkeypatch.setattr(numba_patches, "FLAG_VALUES_SHA256", "0" * 64)
    assert numba_patches.faster_flag_values() is False
    assert TargetConfig.values is values_original


def test_flag_values_ask_each_option_of_a_class_that_overrides_one(values_original):
    from numba.core.compiler import Flags

    class Odd(Flags):
        pass

    Odd.nrt = property(lambda self: "always")  # after the metaclass made its own
    flags = Odd()
    assert numba_patches.flag_values(flags) == values_original(flags)
    assert numba_patches.flag_values(flags)["nrt"] == "always"


@pytest.fixture
def finalize_original(monkeypatch):
    """numba's own ``CPUTargetOptions.finalize`` in place for the test (restored after)."""
    from numba.core.cpu import CPUTargetOptions

    return _numbas_own(monkeypatch, CPUTargetOptions, "finalize")


def _cfunc_wrapped(kernel) -> bool:
    """Whether ``kernel``'s one signature was compiled with its C-callable wrapper."""
    cres = kernel.overloads[kernel.signatures[0]]
    return cres.fndesc.llvm_cfunc_wrapper_name in cres.library.get_llvm_str()


def test_kernels_compile_without_the_cfunc_wrapper_and_run_the_same(finalize_original):
    from numba.core.cpu import CPUTargetOptions

    a = np.linspace(-2.0, 5.0, 11)
    theirs = _inlining_source()
    want = theirs(a, np.empty_like(a), 5)
    assert numba_patches.no_cfunc_wrappers() is True
    assert CPUTargetOptions.finalize.__wrapped__ is finalize_original
    assert numba_patches.no_cfunc_wrappers() is True  # idempotent
    ours = _inlining_source()
    np.testing.assert_array_equal(ours(a, np.empty_like(a), 5), want)  # called from Python
    assert _cfunc_wrapped(theirs) and not _cfunc_wrapped(ours)
    # the same instructions, fewer of them (local labels and the copies of a
    # constant string renumber: a function fewer)
    mine, full = (re.sub(r'(\.const\.[^"]*?)\.\d+"', r'\1"', re.sub(
        r"\.L(BB|func_end|tmp|CPI)\d+(_\d+)?", ".L", _same_names(k.inspect_asm(k.signatures[0]))
    )).splitlines() for k in (ours, theirs))
    assert len(mine) < len(full) and set(mine) <= set(full)


def test_a_kernel_that_asks_for_its_cfunc_wrapper_and_numba_cfunc_keep_it(finalize_original):
    import ctypes

    assert numba_patches.no_cfunc_wrappers() is True
    asked = nb.njit(no_cfunc_wrapper=False)(lambda x: x + 1.0)
    assert asked(1.0) == 2.0 and _cfunc_wrapped(asked)
    callback = nb.cfunc("float64(float64)")(lambda x: x * 2.0)
    assert callback.ctypes(ctypes.c_double(1.5)) == 3.0


@pytest.fixture
def emissions(monkeypatch):
    """numba's own library methods in place for the test; the libraries optimised and emitted.

    numba's ``_optimize_final_module`` and ``_finalize_final_module`` (where a
    library's module is optimised, and its machine code emitted) are wrapped to
    record each library's name before :func:`link_only_machine_code` wraps them in
    turn, so the lists hold what the patch let numba do.
    """
    import functools

    from numba.core import compiler
    from numba.core.codegen import CPUCodeLibrary, JITCodeLibrary

    # numba's own compile_ir too (parfor_bodies_linked_only wraps it)
    compile_ir = compiler.compile_ir
    monkeypatch.setattr(compiler, "compile_ir", getattr(compile_ir, "__wrapped__", compile_ir))
    for key, digest in numba_patches.LINK_ONLY_SHA256.items():
        owner = JITCodeLibrary if key.startswith("JIT") else CPUCodeLibrary
        _numbas_own(monkeypatch, owner, key.split(".")[1], digest)
    done: dict[str, list[str]] = {"optimised": [], "emitted": []}
    for step, name in (("optimised", "_optimize_final_module"),
                       ("emitted", "_finalize_final_module")):
        numbas = getattr(CPUCodeLibrary, name)

        def recorded(self, numbas=numbas, names=done[step]):
            names.append(str(self.name))
            return numbas(self)

        # its source is still numba's to the patch's check
        monkeypatch.setattr(CPUCodeLibrary, name, functools.wraps(numbas)(recorded))
    return done


def _wrappers(names: list[str]) -> list[str]:
    return [n for n in names if n == "parallelgufuncwrapper" or "GufuncWrapper" in n]


def test_a_parallel_kernels_wrappers_are_linked_never_optimised_or_emitted(emissions):
    from numba.core.codegen import CPUCodeLibrary

    a = np.linspace(-2.0, 5.0, 11)
    want = _parallel_source()(a, np.empty_like(a), 5)
    numbas = {step: list(names) for step, names in emissions.items()}
    assert len(_wrappers(numbas["emitted"])) == len(_wrappers(numbas["optimised"])) == 2
    for names in emissions.values():
        names.clear()
    assert numba_patches.link_only_machine_code() is True
    assert numba_patches.link_only_machine_code() is True  # idempotent
    assert CPUCodeLibrary.finalize.__wrapped__ is not None
    np.testing.assert_array_equal(_parallel_source()(a, np.empty_like(a), 5), want)
    for step, names in emissions.items():
        assert any(n.endswith(".f") for n in names), step  # the kernel
        assert any("parfor_gufunc" in n for n in names), step  # its entry point was asked for
        assert _wrappers(names) == [], step
        assert len(names) == len(numbas[step]) - 2, step


def test_a_prange_body_is_linked_never_optimised_or_emitted_on_its_own(emissions):
    from numba.core import compiler

    a = np.linspace(-2.0, 5.0, 11)
    want = _parallel_source()(a, np.empty_like(a), 5)
    assert numba_patches.link_only_machine_code() is True
    assert numba_patches.parfor_bodies_linked_only() is True
    assert numba_patches.parfor_bodies_linked_only() is True  # idempotent
    assert compiler.compile_ir.__wrapped__ is not None
    for names in emissions.values():
        names.clear()
    np.testing.assert_array_equal(_parallel_source()(a, np.empty_like(a), 5), want)
    for step, names in emissions.items():
        assert any(n.endswith(".f") for n in names), step  # the kernel
        assert not any("parfor_gufunc" in n for n in names), (step, names)  # its body
        assert _wrappers(names) == [], step


def test_parfor_bodies_patch_leaves_another_numba_alone(emissions, monkeypatch):
    from numba.core import compiler

    monkeypatch.setattr(numba_patches, "PARFOR_BODY_SHA256", "0" * 64)
    before = compiler.compile_ir
    assert numba_patches.parfor_bodies_linked_only() is False
    assert compiler.compile_ir is before


_LINKED = '''
import sys
from service import numba_patches
if sys.argv[1] == "patched":
    assert numba_patches.link_only_machine_code()
    assert numba_patches.parfor_bodies_linked_only()
import numpy as np
import kern
a = np.arange(12.0)
print(kern.f(a, np.empty_like(a)).sum(), sum(kern.f.stats.cache_hits.values()),
      sum(kern.f.stats.cache_misses.values()))
'''


@pytest.mark.timeout(240)
def test_a_kernel_compiled_so_is_cached_and_loads_without_the_patch(tmp_path):
    """The object code of a kernel whose body and wrappers were never emitted is saved and loads."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    (tmp_path / "kern.py").write_text(
        "import numba\n\n@numba.njit(parallel=True, cache=True)\ndef f(a, b):\n"
        "    for i in numba.prange(a.shape[0]):\n        b[i] = a[i] * a[i] + 1.0\n"
        "    return b\n")
    root = Path(__file__).resolve().parents[2]
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"),
               PYTHONPATH=os.pathsep.join((str(root), str(tmp_path))))

    def run(how: str) -> list[str]:
        out = subprocess.run([sys.executable, "-c", _LINKED, how], env=env, cwd=tmp_path,
                             capture_output=True, text=True, timeout=200, check=True)
        return out.stdout.split()

    want = str(sum(x * x + 1.0 for x in range(12)))
    compiled = run("patched")
    assert compiled == [want, "0", "1"], compiled  # a miss: compiled here, then saved
    assert run("numba's own") == [want, "1", "0"]  # a hit: its object code loaded


def test_link_only_leaves_another_numba_alone(emissions, monkeypatch):
    from numba.core.codegen import CPUCodeLibrary

    digests = dict(numba_patches.LINK_ONLY_SHA256, **{"CPUCodeLibrary.finalize": "0" * 64})
    monkeypatch.setattr(numba_patches, "LINK_ONLY_SHA256", digests)
    before = CPUCodeLibrary.finalize
    assert numba_patches.link_only_machine_code() is False
    assert CPUCodeLibrary.finalize is before


@pytest.fixture
def live_original(monkeypatch):
    """numba's own ``compute_live_map`` in place everywhere it is called from (restored after)."""
    from numba.core import analysis

    original = _numbas_own(monkeypatch, analysis, "compute_live_map",
                           numba_patches.LIVE_MAP_SHA256)
    monkeypatch.setattr(ir_utils, "compute_live_map", original)
    monkeypatch.setattr(parfor, "compute_live_map", original)
    return original


def test_live_map_is_numbas_set_for_set_on_real_compiles(live_original, monkeypatch):
    """Every liveness numba computes compiling two parallel kernels: ours gives its result."""
    from numba.core import analysis

    calls = []

    def both(cfg, blocks, uses, defs):
        theirs = live_original(cfg, blocks, uses, defs)
        calls.append((numba_patches.live_map(cfg, blocks, uses, defs), theirs))
        return theirs

    for module in (analysis, ir_utils, parfor):
        monkeypatch.setattr(module, "compute_live_map", both)
    a = np.linspace(-2.0, 5.0, 11)
    _parallel_source()(a, np.empty_like(a), 5)
    _inlining_source()(a, np.empty_like(a), 5)
    assert len(calls) > 10
    for ours, theirs in calls:
        assert ours == theirs
    assert sum(len(v) for _, theirs in calls for v in theirs.values()) > 100  # not all empty


def test_live_map_patch_is_applied_once_and_compiles_the_same(live_original):
    from numba.core import analysis

    a = np.linspace(-2.0, 5.0, 11)
    want = _inlining_source()(a, np.empty_like(a), 5)
    assert numba_patches.faster_live_map() is True
    assert numba_patches.faster_live_map() is True  # idempotent
    assert analysis.compute_live_map is parfor.compute_live_map is numba_patches.live_map
    assert numba_patches.live_map.__wrapped__ is live_original
    np.testing.assert_array_equal(_inlining_source()(a, np.empty_like(a), 5), want)


def test_live_map_leaves_another_numba_alone(live_original, monkeypatch):
    from numba.core import analysis

    monkeypatch.setattr(numba_patches, "LIVE_MAP_SHA256", "0" * 64)
    assert numba_patches.faster_live_map() is False
    assert analysis.compute_live_map is live_original
