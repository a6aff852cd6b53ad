"""service.numba_subroutine: functions compiled only into the kernels that call them."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numba as nb
import numpy as np
import pytest

from service.numba_subroutine import SubroutineError, subroutine


def _axpy(a, x, y, out, i, add):
    """out[i] = a x[i] + y[i] (add) or a x[i] - y[i]."""
    if add:
        out[i] = a * x[i] + y[i]
    else:
        out[i] = a * x[i] - y[i]


def test_a_parallel_kernel_calls_it_with_each_constant():
    """Two kernels pass True and False: one version each, computing its branch."""
    axpy = subroutine(constants=("add",))(_axpy)

    @nb.njit(parallel=True, cache=False)
    def plus(a, x, y, out):
        for i in nb.prange(x.shape[0]):
            axpy(a, x, y, out, np.int64(i), True)  # one type in both typings of the body

    @nb.njit(cache=False)
    def minus(a, x, y, out):
        for i in range(x.shape[0]):
            axpy(a, x, y, out, i, False)

    x, y = np.arange(1000.0), np.linspace(0.0, 1.0, 1000)
    out = np.empty_like(x)
    plus(2.0, x, y, out)
    np.testing.assert_array_equal(out, 2.0 * x + y)
    minus(3, x, y, out)  # an int for a float: typed as the caller's variable
    np.testing.assert_array_equal(out, 3 * x - y)
    flags = sorted(str(key[-1]) for key in axpy.compiled)
    assert flags == ["Literal[bool](False)", "Literal[bool](True)"]


def test_a_constant_parameter_passed_a_variable_is_a_typing_error():
    axpy = subroutine(constants=("add",))(_axpy)

    @nb.njit(cache=False)
    def kernel(x, out, add):
        axpy(1.0, x, x, out, 0, add)

    with pytest.raises(SubroutineError, match="add must be a constant, not bool"):
        kernel(np.ones(3), np.ones(3), True)


def _broken(x, add):
    """A body that does not type: ``undefined_name`` is no global."""
    if add:
        return x + undefined_name  # noqa: F821 -- the typing error under test
    return x


def test_a_body_that_fails_to_compile_reports_its_own_error():
    """numba retries a failed typing with the constants unliteral: the body's error is kept."""
    broken = subroutine(constants=("add",))(_broken)

    @nb.njit(cache=False)
    def kernel(x):
        return broken(x, True)

    with pytest.raises(nb.core.errors.TypingError, match="undefined_name") as err:
        kernel(1.0)
    assert "must be a constant" not in str(err.value)


def test_an_unknown_constant_is_refused_where_it_is_declared():
    with pytest.raises(SubroutineError, match=r"has no parameter \['sub'\]"):
        subroutine(constants=("sub",))(_axpy)


def test_it_runs_in_jitted_code_only():
    axpy = subroutine(constants=("add",))(_axpy)
    with pytest.raises(NotImplementedError):
        axpy(1.0, np.ones(1), np.ones(1), np.ones(1), 0, True)


def test_division_by_zero_follows_the_error_model():
    def divide(x, out):
        out[0] = x[0] / x[1]

    quiet = subroutine(error_model="numpy")(divide)
    strict = subroutine()(divide)

    @nb.njit(cache=False)
    def run_quiet(x, out):
        quiet(x, out)

    @nb.njit(cache=False)
    def run_strict(x, out):
        strict(x, out)

    out = np.zeros(1)
    run_quiet(np.array([1.0, 0.0]), out)
    assert out[0] == np.inf
    with pytest.raises(ZeroDivisionError):
        run_strict(np.array([1.0, 0.0]), out)


MODULE = '''
import numba as nb
import numpy as np
from service.numba_subroutine import subroutine

@subroutine(constants=("square",))
def term(x, out, i, square):
    out[i] = x[i] * x[i] if square else 2.0 * x[i]

@nb.njit(cache=True, parallel=True)
def kernel(x, out):
    for i in nb.prange(x.shape[0]):
        term(x, out, np.int64(i), True)
'''

RUN = '''
import json, sys
import numpy as np
sys.path.insert(0, sys.argv[1])
import subkernel
x = np.arange(50.0)
out = np.empty_like(x)
subkernel.kernel(x, out)
print(json.dumps({"right": bool(np.array_equal(out, x * x)),
                  "compiled": len(subkernel.term.compiled)}))
'''


def test_the_callers_cache_entry_holds_its_code(tmp_path: Path):
    """A cached kernel loads in a new process without compiling the subroutine again."""
    (tmp_path / "subkernel.py").write_text(textwrap.dedent(MODULE))
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    runs = []
    for _ in range(2):
        done = subprocess.run([sys.executable, "-c", RUN, str(tmp_path)], env=env,
                              capture_output=True, text=True, timeout=300, check=True)
        runs.append(json.loads(done.stdout.strip().splitlines()[-1]))
    assert runs == [{"right": True, "compiled": 1}, {"right": True, "compiled": 0}]
    index = sorted(p.name for p in (tmp_path / "cache").rglob("*.nbi"))
    assert len(index) == 1 and "kernel" in index[0]  # no entry of the subroutine's own


def test_it_returns_values_and_with_nrt_allocates():
    def stats(x):
        """(sum, running sums) of x: a tuple and a new array."""
        run = np.empty_like(x)
        s = 0.0
        for i in range(x.shape[0]):
            s += x[i]
            run[i] = s
        return s, run

    sub = subroutine(nrt=True)(stats)

    @nb.njit(cache=False)
    def kernel(x):
        total, run = sub(x)
        return total, run

    x = np.arange(6.0)
    total, run = kernel(x)
    assert total == 15.0
    np.testing.assert_array_equal(run, np.cumsum(x))
