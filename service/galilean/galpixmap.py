"""Galpixmaps G(n), n = 0..3, stored as structure-of-arrays (seed 002, sections 2.4 and 3.1).

Every field is its own array (component planes first), so the colour planes are an
ordinary frame buffer and the motion planes sit beside them, as section 3.1 asks
for a retrofit.  Shapes use Z zones, H rows and W columns of the *logical* map,
which may include an out-of-view margin around the display (see ``stage``).
Interleaving the fields (array-of-structs) was measured for the scatter and not
adopted: docs/galilean.md, "interleaved storage for the scatter".

=========  ===========================  =====================================================
field      shape, dtype                 meaning
=========  ===========================  =====================================================
colour     (3, Z, H, W) float32         r, g, b in 0..255 (unclipped while propagating)
depth      (Z, H, W) int32              -z in units 2^-fz, smaller is nearer; Z_EMPTY empty
frac       (2, Z, H, W) int16           fractional x, y position, units 2^-fp px,
                                        in [-2^(fp-1), 2^(fp-1))
motion     (2n, Z, H, W) int32          vx, vy, ax, ay, jx, jy (first 2n), units 2^-fm
zmotion    (n, Z, H, W) int32           vz, az, jz (first n), units 2^-(fz + fm - fp)
dcolour    (4 or 0, Z, H, W) float32    dA/dt, dB/dt, dC/dt, d2A/dt2 per refresh
                                        (equations 17-18); 0 planes when switched off
debris     (Z, H, W) uint8              1: debris (no motion, never overrides a galpixel)
obj        (Z, H, W) int32              scene object index of the galpixel, -1 none
=========  ===========================  =====================================================
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from service.base.errors import HoloError
from service.galilean.fixed_point import Z_EMPTY, FixedPoint

#: Highest galpixmap order implemented.
MAX_ORDER = 3

#: A, B, C encoding of equation 17, rows A, B, C; columns r, g, b.
RGB_TO_ABC = np.array([[1, 1, 1], [2, -1, -1], [1, -2, 1]], np.float64) / 3.0
#: Its inverse, equation 18: r = A + B, g = A - C, b = A - B + C.
ABC_TO_RGB = np.array([[1, 1, 0], [1, 0, -1], [1, -1, 1]], np.float64)


class GalileanError(HoloError, ValueError):
    """Galilean-stage input is malformed (the message names the field)."""


#: field name -> (dtype, leading planes as a function of (order, colour planes)).
_LAYOUT = {
    "colour": (np.float32, lambda n, k: 3),
    "depth": (np.int32, None),
    "frac": (np.int16, lambda n, k: 2),
    "motion": (np.int32, lambda n, k: 2 * n),
    "zmotion": (np.int32, lambda n, k: n),
    "dcolour": (np.float32, lambda n, k: k),
    "debris": (np.uint8, None),
    "obj": (np.int32, None),
}
#: The fields in the order of :meth:`Galpixmap.arrays`, the kernels' and the wire's order.
FIELDS = tuple(_LAYOUT)
#: Fields with leading planes, ``(planes, R, C)``: colour, frac, motion, zmotion, dcolour.
PLANE_FIELDS = tuple(k for k, (_, planes) in _LAYOUT.items() if planes is not None)
#: Fields of one value per galpixel, ``(R, C)``: depth, debris, obj.
PIXEL_FIELDS = tuple(k for k, (_, planes) in _LAYOUT.items() if planes is None)


@dataclass
class Galpixmap:
    """A G(``order``) galpixmap; see the module notes for the fields."""

    order: int
    fixed: FixedPoint
    colour: np.ndarray
    depth: np.ndarray
    frac: np.ndarray
    motion: np.ndarray
    zmotion: np.ndarray
    dcolour: np.ndarray
    debris: np.ndarray
    obj: np.ndarray

    def __post_init__(self) -> None:
        self.validate()

    @property
    def shape(self) -> tuple[int, int, int]:
        """(Z, H, W)."""
        return tuple(self.depth.shape)  # type: ignore[return-value]

    @property
    def colour_planes(self) -> int:
        """4 when colour derivatives are carried, else 0."""
        return int(self.dcolour.shape[0])

    def validate(self) -> None:
        """Check every field's shape and dtype.

        Raises
        ------
        GalileanError
            Naming the first field that does not fit.
        """
        if self.order not in range(MAX_ORDER + 1):
            raise GalileanError(f"galpixmap order must be 0..{MAX_ORDER}, got {self.order!r}")
        if not isinstance(self.depth, np.ndarray) or self.depth.ndim != 3:
            raise GalileanError("galpixmap field 'depth' must be a (Z, H, W) array")
        base = self.depth.shape
        k = np.asarray(self.dcolour).shape[0] if np.ndim(self.dcolour) == 4 else -1
        if k not in (0, 4):
            raise GalileanError("galpixmap field 'dcolour' must have 0 or 4 planes")
        for name, (dtype, planes) in _LAYOUT.items():
            arr = getattr(self, name)
            want = base if planes is None else (planes(self.order, k), *base)
            if not isinstance(arr, np.ndarray) or arr.shape != want or arr.dtype != dtype:
                got = getattr(arr, "shape", None), getattr(arr, "dtype", None)
                raise GalileanError(
                    f"galpixmap field {name!r} must be {want} {np.dtype(dtype)}, got {got}"
                )

    @classmethod
    def empty(
        cls,
        order: int,
        fixed: FixedPoint,
        shape: tuple[int, int, int],
        colour_motion: bool = True,
        slot: int = 0,
    ) -> Galpixmap:
        """An all-debris map ("clear-frame debris": black, empty depth, no object).

        ``slot`` staggers its planes after those of maps in lower slots (see
        :func:`_alloc`): give maps that one loop reads and writes together
        different slots (the stage: its map 0, its spare 1, the obscuration
        cache 2 and 3; an update buffer grafted into them :data:`BUFFER_SLOT`).
        """
        k = 4 if colour_motion else 0
        specs = [(tuple(shape), dtype, None if planes is None else planes(order, k))
                 for dtype, planes in _LAYOUT.values()]
        total = sum(1 if p is None else int(p) for _, _, p in specs)
        arrays = dict(zip(_LAYOUT, _alloc(specs, slot * total), strict=True))
        arrays["depth"][:] = Z_EMPTY
        arrays["debris"][:] = 1
        arrays["obj"][:] = -1
        return cls(order=order, fixed=fixed, **arrays)

    def copy(self) -> Galpixmap:
        """A deep copy."""
        kw = {f.name: getattr(self, f.name) for f in fields(self)}
        kw.update({n: getattr(self, n).copy() for n in _LAYOUT})
        return Galpixmap(**kw)

    def arrays(self) -> tuple:
        """The fields as the tuple the kernels take (order of :data:`FIELDS`)."""
        return tuple(getattr(self, n) for n in FIELDS)

    def window(self, margin: int) -> tuple[np.ndarray, np.ndarray]:
        """Displayed part: colour (Z, R, C, 3) uint8 and depth (Z, R, C) float32."""
        z, h, w = self.shape
        sl = (slice(None), slice(margin, h - margin), slice(margin, w - margin))
        col = np.clip(np.rint(self.colour[(slice(None), *sl)]), 0, 255).astype(np.uint8)
        return np.ascontiguousarray(np.moveaxis(col, 0, -1)), self.fixed.depth_float(self.depth[sl])


#: Bytes per cache line, and lines per page (the L1 sets a page spans).
_LINE, _PAGE = 64, 4096
#: Bytes of a transparent huge page (x86-64), and the buffer size from which numpy
#: asks the kernel for them (``madvise(MADV_HUGEPAGE)`` on allocations of 4 MiB and more).
_HUGE, _HUGE_FROM = 2 << 20, 4 << 20
#: The :meth:`Galpixmap.empty` slot of update buffers (:func:`build`): after the
#: stage's map and spare (0, 1), so a graft's copy does not alias its target.
BUFFER_SLOT = 2


def _alloc(specs: list[tuple], first: int = 0) -> list[np.ndarray]:
    """Zeroed arrays for ``(shape, dtype, planes)`` specs, planes staggered, in one buffer.

    Each array is ``(planes, *shape)`` (``shape`` if ``planes`` is None).  The
    n-th plane (over all specs, zero-size ones included) starts on cache line
    ``first + n`` modulo the page; :meth:`Galpixmap.empty` passes its slot times
    its plane count, so maps in different slots take different lines.

    A propagation reads or writes every plane of two maps at the same pixel at
    once.  Plain contiguous planes whose size is a multiple of the page (640x480:
    300 pages of float32) all start at the same address modulo 4 KiB: the ~40
    streams then fight over one L1 set (12 ways) and each load waits on the
    stores it falsely aliases, several times the cost of the copy itself.  Here
    every plane starts on its own cache line modulo the page: each plane stays
    C-contiguous (``flat`` views still work) and the plane axis just gets a stride
    one line longer than a whole number of pages.

    All of a map's fields share one buffer, started on a huge-page boundary when
    it is large enough for numpy to ask for transparent huge pages (a 640x480 map
    is about 17 MB): the ~40 streams of a refresh then cross 2 MiB pages instead
    of 4 KiB ones, which saves TLB misses (the head-turn scatter 4 % less CPU;
    docs/galilean.md, "huge pages").  Where the kernel gives no huge pages the
    layout is the same, only the alignment is wasted.
    """
    plans: list[tuple | None] = []
    total, line = 0, first
    for shape, dtype, planes in specs:
        dt = np.dtype(dtype)
        k = 1 if planes is None else int(planes)
        size = int(np.prod(shape)) * dt.itemsize
        if k == 0 or size == 0:
            line += k
            plans.append(None)
            continue
        step = -(-size // _PAGE) * _PAGE + _LINE
        start = (line * _LINE) % _PAGE
        line += k
        plans.append((total + start, step, k, dt))
        total += -(-(start + k * step) // _PAGE) * _PAGE
    align = _HUGE if total >= _HUGE_FROM else _PAGE
    buf = np.zeros(total + align, np.uint8)
    base = (-buf.ctypes.data) % align
    out = []
    for (shape, dtype, planes), plan in zip(specs, plans, strict=True):
        if plan is None:
            out.append(np.zeros(shape if planes is None else (int(planes), *shape), dtype))
            continue
        off, step, k, dt = plan
        inner = tuple(int(x) * dt.itemsize for x in np.cumprod((1, *shape[::-1]))[:-1][::-1])
        if planes is None:
            out.append(np.ndarray(shape, dt, buf, base + off, inner))
        else:
            out.append(np.ndarray((k, *shape), dt, buf, base + off, (step, *inner)))
    return out


def rgb_to_abc(rgb: np.ndarray) -> np.ndarray:
    """Equation 17 on the last axis: (..., 3) r, g, b -> (..., 3) A, B, C."""
    return np.asarray(rgb, np.float64) @ RGB_TO_ABC.T


def abc_to_rgb(abc: np.ndarray) -> np.ndarray:
    """Equation 18 on the last axis: (..., 3) A, B, C -> (..., 3) r, g, b."""
    return np.asarray(abc, np.float64) @ ABC_TO_RGB.T


def _check(name: str, arr: np.ndarray | None, shape: tuple) -> np.ndarray | None:
    if arr is None:
        return None
    a = np.asarray(arr)
    if a.shape != shape:
        raise GalileanError(f"{name} must have shape {shape}, got {a.shape}")
    return a


def _pad(a: np.ndarray, margin: int, value: float) -> np.ndarray:
    if margin == 0:
        return a
    width = [(0, 0)] * (a.ndim - 2) + [(margin, margin), (margin, margin)]
    return np.pad(a, width, constant_values=value)


def build(
    colour: np.ndarray,
    depth: np.ndarray,
    order: int,
    fixed: FixedPoint,
    derivatives: np.ndarray | None = None,
    dcolour: np.ndarray | None = None,
    obj: np.ndarray | None = None,
    margin: int = 0,
) -> tuple[Galpixmap, dict]:
    """A galpixmap from a render: colour, depth and per-pixel apparent motion.

    Parameters
    ----------
    colour : ndarray, shape (Z, R, C, 3), uint8 or float
    depth : ndarray, shape (Z, R, C)
        +inf where nothing was drawn (an empty background galpixel, no motion).
    order : int
        0..3; derivatives above the order are dropped.
    fixed : FixedPoint
    derivatives : ndarray, shape (D, 3, Z, R, C), optional
        ``[k, c]``: the (k+1)-th time derivative of component c (x, y in px, z in
        depth units) per refresh^(k+1), D >= ``order`` of them (up to 3).  None: no
        motion.
    dcolour : ndarray, shape (4, Z, R, C), optional
        dA, dB, dC, d2A per refresh.  None: colour motion switched off.
    obj : ndarray, shape (Z, R, C), optional
        Object index per pixel (-1 none).
    margin : int
        Out-of-view margin added around the map (debris, depth +inf).

    Returns
    -------
    Galpixmap
    dict
        ``{"clamped": n}``: motion values that were NaN, infinite or beyond the
        integral bits and were clamped.

    Raises
    ------
    GalileanError
        If a field's shape does not match ``depth``'s (the message names it).
    """
    dep = np.asarray(depth, np.float32)
    if dep.ndim != 3:
        raise GalileanError(f"depth must be (Z, R, C), got {dep.shape}")
    col = _check("colour", colour, (*dep.shape, 3))
    der = None if derivatives is None else np.asarray(derivatives)
    if der is not None and (der.shape[1:] != (3, *dep.shape) or not
                            min(order, 3) <= der.shape[0] <= 3):
        raise GalileanError(f"derivatives must have shape ({max(order, 1)}..3, 3, "
                            f"{', '.join(map(str, dep.shape))}), got {der.shape}")
    dcol = _check("dcolour", dcolour, (4, *dep.shape))
    ob = _check("obj", obj, dep.shape)
    gp = Galpixmap.empty(order, fixed, tuple(dep.shape), dcol is not None, BUFFER_SLOT)
    gp.colour[:] = np.moveaxis(col, -1, 0)
    gp.depth[:], zclamped = fixed.depth_fixed(dep)
    gp.debris[:] = 0
    if ob is not None:
        gp.obj[:] = ob
    if dcol is not None:
        gp.dcolour[:] = dcol
        gp.dcolour[~np.isfinite(gp.dcolour)] = 0.0
    clamped = int(zclamped.sum())
    if der is not None and order > 0:
        finite = gp.depth != Z_EMPTY
        limits = (fixed.v_max, fixed.a_max, fixed.j_max)
        for k in range(order):
            q, bad = fixed.quantise(der[k, :2], limits[k], finite)
            gp.motion[2 * k : 2 * k + 2] = q
            gp.zmotion[k], zbad = fixed.zmotion_fixed(der[k, 2], finite)
            clamped += int(bad.sum() + zbad.sum())
    if margin:
        gp = _padded(gp, margin)
    return gp, {"clamped": clamped}


def _padded(gp: Galpixmap, margin: int) -> Galpixmap:
    """``gp`` with an out-of-view margin of debris (depth +inf, obj -1) around it."""
    fill = {"depth": Z_EMPTY, "debris": 1, "obj": -1}
    kw = {n: _pad(getattr(gp, n), margin, fill.get(n, 0)) for n in _LAYOUT}
    return Galpixmap(order=gp.order, fixed=gp.fixed, **kw)
