"""Compile-time fixes to numba internals, applied before the warm-up compiles.

numba 0.68's parallel passes propagate copies (``numba.core.ir_utils.copy_propagate``)
by a fixed-point iteration that deep-copies its whole table of copies at every
round to compare it with the last: a dict of sets of ``(name, name)`` string pairs,
which a shallow copy of each set snapshots just as well (strings and tuples are
immutable).  On the Galilean scatter kernels, whose ``prange`` body is about 350
lines, that deep copy took 17 of the 82 s of CPU their cold compile took, and
20 s of the whole warm-up's 180 s (docs/compile-time.md, "2026-11-26, fourth
session").  :func:`faster_copy_propagation` swaps in the same iteration with the
shallow snapshot: the same copies found, so the same IR and machine code, and
numba's cache sees no difference.

The fix applies only to the function it was written against: if numba's source
of ``copy_propagate`` differs (another numba version), numba is left alone.
"""

from __future__ import annotations

import hashlib
import inspect
from collections.abc import Callable

#: sha256 of the ``copy_propagate`` source the replacement reproduces (numba 0.68.1).
COPY_PROPAGATE_SHA256 = "b607f90ff29db1cef4a6ca4f00481dd308f300e829154053daea3d3066305b62"


def _source_digest(fn: Callable) -> str:
    """sha256 of a function's source text."""
    return hashlib.sha256(inspect.getsource(fn).encode()).hexdigest()


def _snapshot(copies: dict) -> dict:
    """``{label: frozenset}`` of ``{label: set of (name, name)}``: an immutable copy."""
    return {label: frozenset(pairs) for label, pairs in copies.items()}


def copy_propagate(blocks: dict, typemap: dict) -> tuple[dict, dict]:
    """Numba's ``copy_propagate`` with a shallow snapshot in place of ``copy.deepcopy``.

    Data-flow equations, iterated to a fixed point: ``in_b`` is the intersection of
    the predecessors' ``out``, ``out_b = gen_b | (in_b - kill_b)``.  (numba's
    ``NUMBA_DEBUG_ARRAY_OPT`` print of the result is left out.)

    Parameters
    ----------
    blocks : dict
        Label -> ``numba.core.ir.Block``.
    typemap : dict
        Variable name -> numba type.

    Returns
    -------
    tuple of dict
        ``(in_copies, out_copies)``: label -> set of ``(lhs, rhs)`` names.
    """
    from numba.core.ir_utils import compute_cfg_from_blocks, init_copy_propagate_data

    cfg = compute_cfg_from_blocks(blocks)
    entry = cfg.entry_point()
    gen_copies, _, kill_copies, in_copies, out_copies = init_copy_propagate_data(
        blocks, entry, typemap
    )
    old_point = None
    new_point = _snapshot(out_copies)
    while old_point != new_point:
        for label in blocks.keys():
            if label == entry:
                continue
            predecs = [i for i, _d in cfg.predecessors(label)]
            in_copies[label] = out_copies[predecs[0]].copy()
            for p in predecs:
                in_copies[label] &= out_copies[p]
            out_copies[label] = gen_copies[label] | (in_copies[label] - kill_copies[label])
        old_point = new_point
        new_point = _snapshot(out_copies)
    return in_copies, out_copies


def faster_copy_propagation() -> bool:
    """Use :func:`copy_propagate` in numba's parallel passes; True if it is in use.

    Idempotent.  Leaves numba alone (returns False) unless its ``copy_propagate``
    is the source this module reproduces; numba's stays reachable as
    ``copy_propagate.__wrapped__``.
    """
    from numba.core import ir_utils
    from numba.parfors import parfor

    if parfor.copy_propagate is copy_propagate:
        return True
    if _source_digest(ir_utils.copy_propagate) != COPY_PROPAGATE_SHA256:
        return False
    copy_propagate.__wrapped__ = ir_utils.copy_propagate  # numba's, for a test to compare
    ir_utils.copy_propagate = copy_propagate
    parfor.copy_propagate = copy_propagate
    return True
