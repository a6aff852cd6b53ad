"""service.numba_patches: numba's copy propagation, the same result at less cost."""

from __future__ import annotations

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
