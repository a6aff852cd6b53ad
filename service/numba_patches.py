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

:func:`faster_inlining` does the like for the inliner's copy of a callee's IR (one
deepcopy memo for all its blocks), :func:`faster_flag_values` for the comparison of
compiler flags that typing does at every call it resolves, :func:`faster_live_map`
for liveness (bit sets instead of sets of names); :func:`no_cfunc_wrappers` skips a
wrapper no kernel here uses, :func:`link_only_machine_code` the optimisation and
machine code of libraries only ever linked into a kernel (a parallel loop's gufunc
wrappers), and :func:`locked_cache_saves` makes numba's cache saves atomic between
processes.
:func:`apply_all` applies every one.

Each fix applies only to the function it was written against: if numba's source
differs (another numba version), numba is left alone.
"""

from __future__ import annotations

import functools
import hashlib
import inspect
import os
import textwrap
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
    # deferred: numba's compiler internals load only when a patch is applied
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
    # deferred: numba's compiler internals load only when a patch is applied
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


#: File in a numba cache folder that :func:`locked_cache_saves` locks around a save.
CACHE_LOCK = ".holo-cache.lock"


def _locked(save: Callable) -> Callable:
    """``save`` run under an exclusive ``flock`` of the cache folder's :data:`CACHE_LOCK`."""
    # deferred: POSIX only: the module still imports elsewhere
    import fcntl

    @functools.wraps(save)
    def locked_save(self, key, data) -> None:  # noqa: ANN001 -- numba's own arguments
        try:
            fd = os.open(os.path.join(self._cache_path, CACHE_LOCK), os.O_RDWR | os.O_CREAT,
                         0o644)
        except OSError:  # a read-only cache: numba's own save fails quietly there too
            return save(self, key, data)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            return save(self, key, data)
        finally:
            os.close(fd)  # closing releases the lock

    return locked_save


def locked_cache_saves() -> bool:
    """Make numba's cache saves atomic between processes; True if in use.

    numba adds a kernel signature to its cache by reading the kernel's index,
    taking the first free data-file number and writing the index and the data
    file (``IndexDataCacheFile.save``).  Two processes adding different signatures
    of one kernel at once can both take number 1, and the index then names the
    other's machine code.  Under an exclusive ``flock`` of one file per cache folder
    the read-number-write is one step (a few milliseconds per compile, never held
    while compiling).  The service's background compile (:mod:`service.readiness`)
    runs beside processes that may compile too.  Idempotent; POSIX only (False
    elsewhere).
    """
    try:
        import fcntl  # noqa: F401 -- POSIX only
    except ImportError:
        return False
    # deferred: numba's compiler internals load only when a patch is applied
    from numba.core.caching import IndexDataCacheFile

    if getattr(IndexDataCacheFile.save, "__wrapped__", None) is None:
        IndexDataCacheFile.save = _locked(IndexDataCacheFile.save)
    return True


#: sha256 of ``InlineWorker.inline_ir``'s source that :func:`faster_inlining` edits
#: (numba 0.68.1).
INLINE_IR_SHA256 = "26fd2b7600c9d9295c925c2dd4d498929ef6ae43c09bf285298255527da5362b"
#: numba's copy of a callee's IR: each block deep-copied on its own ...
_COPY_EACH = """            for block_label, block in the_ir.blocks.items():
                new_block = copy.deepcopy(the_ir.blocks[block_label])
"""
#: ... and the same with one memo for all blocks: their shared scope copied once.
_COPY_SHARED = """            memo = {}
            for block_label, block in the_ir.blocks.items():
                new_block = copy.deepcopy(the_ir.blocks[block_label], memo)
"""


def faster_inlining() -> bool:
    """Use numba's ``inline_ir`` with one deepcopy memo for a callee's blocks; True if so.

    Inlining a function (``inline="always"``) copies its IR twice, block by block,
    with ``copy.deepcopy``; every block refers to the function's one ``Scope``, which
    holds every variable of the function, so each block's copy copies the whole
    scope again: blocks x variables (numba issue #8989).  The Galilean scatter's
    body (:mod:`service.galilean.scatter_bands`) has hundreds of blocks; its two
    inlines took 14.7 s of CPU of a cold warm-up (docs/compile-time.md).  One memo
    for all blocks copies the scope once and keeps what the blocks shared shared,
    as in the function's own IR; the inliner then points every inlined block at the
    caller's scope anyway (its step 7), so the inlined code, and the machine code,
    are the same (``tests/warmup/test_numba_patches.py`` compares them).

    numba's source of ``InlineWorker.inline_ir`` with that one edit, compiled in
    numba's module; numba is left alone (False) unless the source is the one this
    was written against (:data:`INLINE_IR_SHA256`).  Idempotent; numba's method stays
    reachable as ``__wrapped__``.
    """
    # deferred: numba's compiler internals load only when a patch is applied
    from numba.core import inline_closurecall as icc

    current = icc.InlineWorker.inline_ir
    if getattr(current, "__wrapped__", None) is not None:
        return True
    source = inspect.getsource(current)
    if _source_digest(current) != INLINE_IR_SHA256 or source.count(_COPY_EACH) != 1:
        return False
    namespace: dict = {}
    code = compile(textwrap.dedent(source.replace(_COPY_EACH, _COPY_SHARED)),
                   inspect.getsourcefile(current) or "<numba inline_ir>", "exec")
    exec(code, vars(icc), namespace)  # noqa: S102 -- numba's own source, checked above
    patched = namespace["inline_ir"]
    patched.__wrapped__ = current
    icc.InlineWorker.inline_ir = patched
    return True


#: sha256 of ``TargetConfig.values``' source that :func:`faster_flag_values` replaces
#: (numba 0.68.1).
FLAG_VALUES_SHA256 = "12a29dc810f6a91beed3ce8a4c2071b278e37cc9031733f0deea8849bcb78611"
#: ``__qualname__`` of the getter numba's ``_MetaTargetConfig`` makes for every option.
_OPTION_GETTER = "_MetaTargetConfig.__init__.<locals>.make_prop.<locals>.getter"


@functools.cache
def _option_defaults(cls: type) -> dict | None:
    """``{option: default}`` of a ``TargetConfig`` class, in its options' order.

    None where an option of ``cls`` is read by anything but numba's own getter (a
    subclass that overrides one): :func:`flag_values` then asks each option.
    """
    for name in cls.options:
        prop = inspect.getattr_static(cls, name, None)
        if not isinstance(prop, property) or prop.fget.__qualname__ != _OPTION_GETTER:
            return None
    return {name: option.default for name, option in cls.options.items()}


def flag_values(self) -> dict:  # noqa: ANN001 -- numba's TargetConfig
    """Every option's value, set or default: numba's ``TargetConfig.values``, cheaper.

    The same dict (the same keys, order and objects) as numba's, which reads each
    option through its property: the class's defaults (worked out once per class)
    updated with the options set.
    """
    defaults = _option_defaults(type(self))
    if defaults is None:
        return {name: getattr(self, name) for name in self.options}
    values = dict(defaults)
    values.update(self._values)
    return values


def faster_flag_values() -> bool:
    """Use :func:`flag_values` for numba's compiler flags; True if it is in use.

    Typing a call to an ``@overload`` function (``max``, ``np.uint64``, ...) looks
    its implementation up in a cache keyed by the compiler's flags, whose hash and
    ``==`` compare ``TargetConfig.values()``: a dict built by reading 22 options
    through properties, twice per comparison, and every flags object hashes alike.
    On the Galilean scatter kernel's cold compile that was 290,000 calls and about
    a tenth of its CPU.  The same dict at a fraction of the cost, so the same
    lookups, types and machine code.  numba is left alone (False) unless its
    ``values`` is the source this replaces (:data:`FLAG_VALUES_SHA256`).
    Idempotent; numba's method stays reachable as ``__wrapped__``.
    """
    # deferred: numba's compiler internals load only when a patch is applied
    from numba.core.targetconfig import TargetConfig

    current = TargetConfig.values
    if current is flag_values:
        return True
    if _source_digest(current) != FLAG_VALUES_SHA256:
        return False
    flag_values.__wrapped__ = current
    TargetConfig.values = flag_values
    return True


def _without_cfunc_wrapper(finalize: Callable) -> Callable:
    """Numba's ``CPUTargetOptions.finalize``, then no C-callable wrapper unless asked for."""

    @functools.wraps(finalize)
    def finalize_flags(self, flags, options) -> None:  # noqa: ANN001 -- numba's own arguments
        finalize(self, flags, options)
        if "no_cfunc_wrapper" not in options:
            flags.no_cfunc_wrapper = True

    return finalize_flags


def no_cfunc_wrappers() -> bool:
    """Compile ``@njit`` kernels without numba's C-callable wrapper; True if in use.

    numba compiles, beside each kernel signature, a wrapper with a C calling
    convention (``llvm_cfunc_wrapper_name``) that only a kernel passed as a
    first-class function value to another kernel needs (``numba.cfunc`` asks for
    its own, after this).  The service passes none, so the wrapper is LLVM work
    for nothing: the first three warm-up jobs took 5-8 % less CPU without it.
    The kernel's own code is the same (a test compares it); the symbols' names
    differ (they carry the flags), which numba's cache does not key on.
    A kernel that sets ``no_cfunc_wrapper`` itself is left as it asks.
    Idempotent; numba's method stays reachable as ``__wrapped__``.
    """
    # deferred: numba's compiler internals load only when a patch is applied
    from numba.core.cpu import CPUTargetOptions

    if getattr(CPUTargetOptions.finalize, "__wrapped__", None) is None:
        CPUTargetOptions.finalize = _without_cfunc_wrapper(CPUTargetOptions.finalize)
    return True


#: sha256 of ``numba.core.analysis.compute_live_map``'s source that :func:`live_map`
#: reproduces (numba 0.68.1).
LIVE_MAP_SHA256 = "713c4c094977e93b7ade48a478eb9b94168786ad9b440906b8e95b7fc0487a2a"


def _bits(names: set, index: dict) -> int:
    """``names`` as an int bit set, numbering each new name in ``index`` (name -> bit)."""
    out = 0
    for name in names:
        bit = index.get(name)
        if bit is None:
            bit = index[name] = len(index)
        out |= 1 << bit
    return out


def _names(bits: int, names: list) -> set:
    """The set of ``names[i]`` for each bit ``i`` set in ``bits``."""
    out = set()
    while bits:
        low = bits & -bits
        out.add(names[low.bit_length() - 1])
        bits ^= low
    return out


def _until_fixed(step: Callable[[], bool]) -> None:
    """Run ``step`` until a pass changes nothing (it returns whether it changed)."""
    while step():
        pass


def live_map(cfg, blocks: dict, var_use_map: dict, var_def_map: dict) -> dict:  # noqa: ANN001
    """Numba's ``compute_live_map`` over int bit sets: the variables live at each block's entry.

    The same two fixed points as numba's (definitions reaching each block, forward in
    topological order; then liveness, backward), each variable a bit of a Python
    int, so a union or intersection is one operation on machine words instead of a
    set operation over names.  Both are least fixed points of monotone equations,
    reached whatever the order of updates, so the result is numba's set for set.

    Parameters
    ----------
    cfg : numba.core.controlflow.CFGraph
        The blocks' control-flow graph.
    blocks : dict
        Label -> block (its keys: the labels of the result).
    var_use_map, var_def_map : dict
        Label -> set of the variable names a block uses / defines.

    Returns
    -------
    dict
        Label -> set of the variable names live at the block's entry.
    """
    topo = cfg.topo_order()
    index: dict = {}
    use = {label: _bits(var_use_map[label], index) for label in topo}
    defs = {label: _bits(var_def_map[label], index) for label in topo}
    succs = {label: [s for s, _ in cfg.successors(label)] for label in topo}
    preds = {label: [p for p, _ in cfg.predecessors(label)] for label in topo}
    reach: dict = {}

    def forward() -> bool:
        changed = False
        for label in topo:
            here = reach.get(label, 0) | defs[label] | use[label]
            reach[label] = here
            for succ in succs[label]:
                old = reach.get(succ, 0)
                if old | here != old:
                    reach[succ] = old | here
                    changed = True
        return changed

    live = {label: _bits(var_use_map[label], index) for label in blocks}
    for label in topo:  # predecessors' own definitions, as numba's KeyError would
        for pred in preds[label]:
            defs.setdefault(pred, _bits(var_def_map[pred], index))

    def backward() -> bool:
        changed = False
        for label in reversed(topo):
            here = live[label]
            for pred in preds[label]:
                old = live[pred]
                new = old | ((here & reach.get(pred, 0)) & ~defs[pred])
                if new != old:
                    live[pred] = new
                    changed = True
        return changed

    _until_fixed(forward)
    _until_fixed(backward)
    names = list(index)
    return {label: _names(bits, names) for label, bits in live.items()}


def faster_live_map() -> bool:
    """Use :func:`live_map` for numba's liveness analysis; True if it is in use.

    numba computes which variables are live at each block's entry for every
    dead-code pass, parfor pass and variable-deletion pass, by fixed points over
    Python sets of names: on the Galilean scatter's ``prange`` body (hundreds of
    blocks, thousands of variables) each union copies whole sets.  cProfile of a
    cold warm-up: 10 s of its CPU.  numba is left alone (False) unless its
    ``compute_live_map`` is the source this reproduces (:data:`LIVE_MAP_SHA256`).
    Idempotent; numba's stays reachable as ``live_map.__wrapped__``.
    """
    # deferred: numba's compiler internals load only when a patch is applied
    from numba.core import analysis, ir_utils
    from numba.parfors import parfor

    if analysis.compute_live_map is live_map:
        return True
    if _source_digest(analysis.compute_live_map) != LIVE_MAP_SHA256:
        return False
    live_map.__wrapped__ = analysis.compute_live_map
    for module in (analysis, ir_utils, parfor):
        module.compute_live_map = live_map
    return True


#: sha256 of the numba sources :func:`link_only_machine_code` wraps (numba 0.68.1): each
#: library's ``finalize`` links, optimises (``_optimize_final_module``), then emits
#: machine code (``_finalize_final_module``); ``get_pointer_to_function`` and
#: ``_get_compiled_object`` are where machine code is read.
LINK_ONLY_SHA256 = {
    "CPUCodeLibrary.finalize":
        "4b4c34b83488a72fea5f3d836a8a9f7281674ab245973287a38c9ca07c78af99",
    "CPUCodeLibrary._optimize_final_module":
        "e405bd473752613ba43e3becff2b625a039c11f111dff9498ac9bfd215e74846",
    "CPUCodeLibrary._finalize_final_module":
        "95bbf4fcbb90ed9904c2ec85158b65a3dff8fab80d1d8af31c25b6885d5a1a5b",
    "JITCodeLibrary.get_pointer_to_function":
        "1bce3f385d25b31c91fff96be087f55e7ec446d816d2df9f68bac48db840858e",
    "CodeLibrary._get_compiled_object":
        "13a61024bb35cbb6effe76c6a9182d60a64dfde475f80cb95c199a7f94a212f1",
}


def _deferring(finalize: Callable) -> Callable:
    """Numba's ``CodeLibrary.finalize``: linked now, optimised and emitted when read."""

    @functools.wraps(finalize)
    def finalize_deferring(self) -> None:  # noqa: ANN001 -- numba's CodeLibrary
        self._holo_defer = True
        try:
            finalize(self)
        finally:
            self._holo_defer = False
        self._finalized = True  # numba's last step, left for later, sets it

    return finalize_deferring


def _later(step: Callable, flag: str) -> Callable:
    """Numba's ``step`` of ``finalize``, skipped inside :func:`_deferring` (``flag`` set)."""

    @functools.wraps(step)
    def step_later(self) -> None:  # noqa: ANN001 -- numba's CodeLibrary
        if getattr(self, "_holo_defer", False):
            setattr(self, flag, True)
            return
        step(self)

    return step_later


def _emitting_first(read: Callable, optimise: Callable, emit: Callable) -> Callable:
    """A reader of a library's machine code; the library optimised and emitted first if not yet."""

    @functools.wraps(read)
    def read_emitted(self, *args, **kwargs):  # noqa: ANN001, ANN202 -- numba's own
        self._ensure_finalized()
        if getattr(self, "_holo_unoptimised", False):
            self._holo_unoptimised = False
            optimise(self)
        if getattr(self, "_holo_pending", False):
            self._holo_pending = False
            emit(self)
        return read(self, *args, **kwargs)

    return read_emitted


def link_only_machine_code() -> bool:
    """Optimise and emit a library's module only when its machine code is read; True if so.

    Each ``prange`` loop of a ``parallel=True`` kernel compiles as a gufunc in a
    library of its own, wrapped by two more (numba's ``_GufuncWrapper`` and
    ``parallelgufuncwrapper``), each linking the one before as LLVM IR, and the
    kernel's library links them all.  numba finalises every library by optimising
    its whole module at ``-O3`` and emitting its machine code, so the loop body,
    most of a parallel kernel, went through LLVM's optimiser and code generator
    four times, though nothing reads the two wrappers' machine code (only the
    kernel's runs and is cached).  Here a library is linked when finalised, and its
    module optimised and emitted when its address or object code is first asked
    for: the kernel's and the gufunc's at once (numba asks for their entry points),
    the wrappers' never; their IR is optimised where it runs, in the kernel's
    module.  Every job of a cold warm-up, one process: 161.8 -> 146.8 s of CPU
    without the wrappers' machine code, and 144.4 -> 136.3 s more without their
    optimisation (docs/compile-time.md, session 7).

    Not byte for byte the same machine code: emitting a module also rewrites its IR
    for the target (LLVM's code generator preparation), and the kernel used to link
    the wrappers' rewritten, re-optimised IR.  Refresh, renders and updates measured
    within their run-to-run spread (about 1 %); outputs are unchanged (the tests).
    numba is left alone (False) unless the sources it wraps are the ones in
    :data:`LINK_ONLY_SHA256`.  Idempotent; numba's methods stay reachable as
    ``__wrapped__``.
    """
    # deferred: numba's compiler internals load only when a patch is applied
    from numba.core import codegen

    library, jit = codegen.CPUCodeLibrary, codegen.JITCodeLibrary
    if getattr(library.finalize, "__wrapped__", None) is not None:
        return True
    current = {
        "CPUCodeLibrary.finalize": library.finalize,
        "CPUCodeLibrary._optimize_final_module": library._optimize_final_module,
        "CPUCodeLibrary._finalize_final_module": library._finalize_final_module,
        "JITCodeLibrary.get_pointer_to_function": jit.get_pointer_to_function,
        "CodeLibrary._get_compiled_object": library._get_compiled_object,
    }
    if any(_source_digest(fn) != LINK_ONLY_SHA256[name] for name, fn in current.items()):
        return False
    optimise, emit = library._optimize_final_module, library._finalize_final_module
    library._optimize_final_module = _later(optimise, "_holo_unoptimised")
    library._finalize_final_module = _later(emit, "_holo_pending")
    library._get_compiled_object = _emitting_first(library._get_compiled_object, optimise,
                                                   emit)
    jit.get_pointer_to_function = _emitting_first(jit.get_pointer_to_function, optimise, emit)
    library.finalize = _deferring(library.finalize)
    return True


#: sha256 of ``numba.parfors.parfor_lowering._create_gufunc_for_parfor_body``'s source
#: (numba 0.68.1), which compiles a ``prange`` body with ``compiler.compile_ir`` and a
#: pipeline class of its own, ``ParforGufuncCompiler``, and hands on its library.
PARFOR_BODY_SHA256 = "82b8b3f21ceffc853ac139f2a7daeda9b8c09d3064ef3183e7a20761b1958dd8"

#: The pipeline class numba compiles a ``prange`` body with.
PARFOR_PIPELINE = "ParforGufuncCompiler"


def _no_compile(flags):  # noqa: ANN001, ANN202 -- numba's Flags
    """A copy of numba's compiler ``flags`` with ``no_compile`` set."""
    flags = flags.copy()
    flags.no_compile = True
    return flags


def _body_without_machine_code(compile_ir: Callable) -> Callable:
    """Wrap numba's ``compile_ir``: a ``prange`` body compiled with ``no_compile`` set."""

    @functools.wraps(compile_ir)
    def compile_ir_linked(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202 -- numba's own
        pipeline = kwargs.get("pipeline_class")
        if getattr(pipeline, "__name__", None) == PARFOR_PIPELINE:
            if "flags" in kwargs:
                kwargs["flags"] = _no_compile(kwargs["flags"])
            else:  # (typingctx, targetctx, func_ir, args, return_type, flags, ...)
                args = (*args[:5], _no_compile(args[5]), *args[6:])
        return compile_ir(*args, **kwargs)

    return compile_ir_linked


def parfor_bodies_linked_only() -> bool:
    """Compile each ``prange`` body's gufunc as IR to link, with no machine code of its own.

    numba compiles the body of every ``prange`` loop as a function of its own (the
    gufunc), asks for its entry point, so its module is optimised at ``-O3`` and its
    machine code emitted (:func:`link_only_machine_code` cannot defer that), then
    links it into the kernel's module, which is optimised and emitted again; only
    the kernel's machine code runs or is cached.  With ``no_compile`` set for the
    body's pipeline it is lowered and linked, never optimised or emitted on its own.
    Not the same machine code: the body is optimised once, in the kernel.  That cost
    the Galilean refresh 1.3-1.6 % while the scatter's whole body was a ``prange``
    body (session 7); since the body is a function of its own (session 8) the
    refresh, renders and updates measured even.  A cold warm-up: about 0.94x the
    CPU (docs/compile-time.md, session 8).  numba is left alone (False) unless its
    source is the one in :data:`PARFOR_BODY_SHA256`.  Idempotent; numba's function
    stays reachable as ``__wrapped__``.
    """
    # deferred: numba's compiler internals load only when a patch is applied
    from numba.core import compiler
    from numba.parfors import parfor_lowering

    if getattr(compiler.compile_ir, "__wrapped__", None) is not None:
        return True
    if _source_digest(parfor_lowering._create_gufunc_for_parfor_body) != PARFOR_BODY_SHA256:
        return False
    compiler.compile_ir = _body_without_machine_code(compiler.compile_ir)
    return True


def apply_all() -> dict[str, bool]:
    """Every patch of this module (what :func:`service.warmup.warm_up` compiles under).

    Returns each patch's name and whether it is in use.
    """
    return {fn.__name__: fn() for fn in (faster_copy_propagation, faster_inlining,
                                          faster_flag_values, faster_live_map,
                                          no_cfunc_wrappers, link_only_machine_code,
                                          parfor_bodies_linked_only,
                                          locked_cache_saves)}
