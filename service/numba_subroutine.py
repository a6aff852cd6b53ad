"""Jitted functions compiled only into the kernels that call them (numba's subroutines).

A function decorated with ``numba.njit`` and called from a kernel is a dispatcher
of its own: numba optimises its module at ``-O3``, emits its machine code, builds
its Python entry point and writes it to the cache, then links its IR into the
kernel, where it is optimised and emitted again.  Only the kernel's machine code
ever runs.  A function decorated with :func:`subroutine` is compiled as numba
compiles its own helpers (``BaseContext.compile_subroutine``): typed and lowered
once per process and signature, when a caller is typed, then linked into each
caller and optimised and emitted there only, with no machine code, entry point or
cache entry of its own (the callers' cache entries hold its code).

It runs as fast as the dispatcher did: the Galilean scatter's band body
(:mod:`service.galilean.scatter_bands`) refreshed within 1 % either way, and its
kernel's cold compile took 0.89x the CPU (docs/compile-time.md, session 9).

In a ``prange`` loop numba types the body twice, the second time with the loop
index unsigned: pass the index as ``np.int64(i)``, so that both typings agree and
the subroutine compiles once.

A subroutine runs in jitted code only: called from Python it raises numba's
``NotImplementedError``.  Without ``nrt`` it may not allocate.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any

from service.base.errors import HoloError


class SubroutineError(HoloError, TypeError):
    """A subroutine declared or called wrongly (a constant argument that is not one)."""


def subroutine(
    *, constants: tuple[str, ...] = (), error_model: str = "python", nrt: bool = False,
) -> Callable:
    """Decorate a Python function as a subroutine of the kernels that call it.

    Parameters
    ----------
    constants : tuple of str
        Parameters the callers pass as constants (``True``, ``3``): each value
        compiles a version of its own, with the branches it rules out removed
        (numba's ``Literal`` types).  Every other argument is typed as a variable.
    error_model : str
        numba's ``error_model``: ``"python"`` (division by zero raises) or
        ``"numpy"``.
    nrt : bool
        Compile with reference counting, so that the function may allocate (its
        callers must have it too, as ``numba.njit`` functions do by default).
        Without it, each array argument, view or array handed to a helper costs
        nothing; with it, an atomic increment and decrement.

    Returns
    -------
    callable
        The decorator.  It returns a numba intrinsic; the versions compiled in
        this process are in its ``compiled`` dict, by argument types.
    """

    def decorate(fn: Callable) -> Any:  # noqa: ANN401 -- numba's intrinsic
        names = list(inspect.signature(fn).parameters)
        unknown = sorted(set(constants) - set(names))
        if unknown:
            raise SubroutineError(f"{fn.__qualname__} has no parameter {unknown}")
        return _intrinsic(fn, tuple(n in constants for n in names), error_model, nrt)

    return decorate


def _compiler(fn: Callable, error_model: str, nrt: bool) -> tuple[Callable, dict]:
    """``compile(typingctx, argtys)``: ``fn`` compiled for ``argtys`` once, and its memo."""
    compiled: dict = {}

    def compile_once(typingctx: Any, argtys: tuple) -> Any:  # noqa: ANN401 -- numba's
        if argtys not in compiled:
            # deferred: numba's compiler loads when a caller is typed, not on import
            from numba.core import compiler
            from numba.core.registry import cpu_target

            flags = compiler.Flags()
            flags.error_model = error_model
            flags.nrt = nrt
            flags.no_compile = flags.no_cpython_wrapper = flags.no_cfunc_wrapper = True
            context = cpu_target.target_context
            library = context.codegen().create_library(fn.__qualname__)
            compiled[argtys] = compiler.compile_internal(
                typingctx, context, library, fn, argtys, None, flags, {})
        return compiled[argtys]

    return compile_once, compiled


def _intrinsic(fn: Callable, literal: tuple[bool, ...], error_model: str,
               nrt: bool) -> Any:  # noqa: ANN401
    """The numba intrinsic that types, compiles and calls ``fn`` (see :func:`subroutine`)."""
    # deferred: numba loads with the first kernel module that declares a subroutine
    from numba.core import types
    from numba.extending import intrinsic

    compile_once, compiled = _compiler(fn, error_model, nrt)
    names = list(inspect.signature(fn).parameters)

    def lower(context, builder, sig, args):  # noqa: ANN001, ANN202 -- numba's codegen
        cres = compile_once(context.typing_context, tuple(sig.args))
        context.active_code_library.add_linking_library(cres.library)
        return context.call_internal(builder, cres.fndesc, sig, args)

    failed: list[Exception] = []  # why the body did not compile for constant arguments

    def typer(typingctx, *args):  # noqa: ANN001, ANN002, ANN202 -- numba's typer
        argtys = []
        for name, keep, ty in zip(names, literal, args, strict=True):
            if keep and not isinstance(ty, types.Literal):
                # numba retries a failed typing with the constants as plain types:
                # the first failure is what went wrong
                if failed:
                    raise failed.pop()
                raise SubroutineError(f"{fn.__qualname__}: {name} must be a constant, not {ty}")
            argtys.append(ty if keep else types.unliteral(ty))
        # compiled now, as numba compiles a dispatcher its caller calls: at lowering,
        # amid the caller's own compile, the same work took 1.3x the CPU (session 9)
        try:
            cres = compile_once(typingctx, tuple(argtys))
        except Exception as exc:
            failed[:] = [exc]
            raise
        failed.clear()
        return cres.signature.return_type(*argtys), lower

    # numba reads the parameters after the typing context as the call's signature
    context = inspect.Parameter("typingctx", inspect.Parameter.POSITIONAL_OR_KEYWORD)
    typer.__signature__ = inspect.Signature(
        [context, *inspect.signature(fn).parameters.values()])
    for attr in ("__name__", "__qualname__", "__doc__", "__module__"):
        setattr(typer, attr, getattr(fn, attr))
    result = intrinsic(prefer_literal=True)(typer)
    result.compiled = compiled
    return result
