"""Compiled kernels: numba where it is installed (the one optional import, and :func:`jit`, the
one decorator of every kernel), and flat workspaces (:class:`Layout` declares a buffer's named
slots once; :func:`view1`, :func:`view2`, :func:`view3` carve them inside a kernel), so every
compiled path (the field query, the filter step, the mapping, perception and simulator kernels)
takes a few flat buffers and a table instead of one argument per array.

Here, beside the wire contract, because the ESDF query (``protocol.field``) is a kernel that
external clients run too: compiled where numba is installed, the same code interpreted where it is
not. The node-side companions (compile progress, thread counts, the install hint) are in
``services.runtime.jit``.

Every kernel is ``cache=True``: numba keeps its machine code on disk and a later process loads it
instead of compiling. Where (numba/core/caching.py, ``CacheImpl._locator_classes``, first that
fits): ``$NUMBA_CACHE_DIR/<folder>_<sha1 of the folder path>/`` when that variable is set
(``UserProvidedCacheLocator``), else ``__pycache__`` next to the source when it is writable
(``InTreeCacheLocator``: the checkout itself for ``pip install -e``), else the user's cache folder
(``UserWideCacheLocator``, ``~/.cache/numba``). An entry is used only for the same source file
(``_SourceFileBackedLocatorMixin.get_source_stamp``: a hash of the file), argument types, numba
version and CPU (``Cache._index_key``, ``CPUCodegen.magic_tuple``). ``riskfield warmup``
(``services/runtime/warmup.py``) fills it once at set-up.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from enum import IntEnum
from typing import Any

import numpy as np

numba: Any
try:
    import numba

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - exercised on installs without numba
    numba = None
    HAVE_NUMBA = False


def jit(fn=None, **options):
    """``numba.njit`` with the on-disk cache (compiled once per install) and without the GIL, plus
    numba's ``options`` (``parallel``, ``inline``, ``error_model``): the one decorator of every
    kernel. Without numba, ``fn`` itself. ``@jit`` and ``@jit(**options)`` both work."""

    def wrap(f):
        return numba.njit(cache=True, nogil=True, **options)(f) if HAVE_NUMBA else f

    return wrap if fn is None else wrap(fn)


class Layout:
    """Named slots of one flat buffer, declared once: the sizes, offsets and shapes that both the
    Python side (allocation, :meth:`view`) and a compiled kernel (:func:`view1`, :func:`view2`,
    :func:`view3` with ``layout.slot.<name>``) use, so no offset is written by hand.

    A slot's shape is a tuple of ints and dimension names (``("q", 3)``) bound by :meth:`table`.
    A call into numba costs per argument (~0.2 µs), so a kernel takes a few flat buffers and this
    table, and carves its views inside.
    """

    def __init__(self, name: str, slots: Sequence[tuple[str, tuple[int | str, ...]]]):
        self.slot = IntEnum(name, [s for s, _ in slots], start=0)  # type: ignore[misc]
        self.shapes = {s: shape for s, shape in slots}

    def table(self, **dims: int) -> np.ndarray:
        """(slots, 4) int64: [offset, d0, d1, d2] per slot (unused trailing dimensions are 1)."""
        rows, at = [], 0
        for shape in self.shapes.values():
            d = [dims[x] if isinstance(x, str) else int(x) for x in shape]
            d += [1] * (3 - len(d))
            rows.append([at, *d])
            at += math.prod(d)
        return np.array(rows, np.int64).reshape(-1, 4)

    @staticmethod
    def size(table: np.ndarray) -> int:
        """Length of the buffer a :meth:`table` describes."""
        return int(table[-1, 0] + table[-1, 1:].prod()) if len(table) else 0

    def view(self, buf: np.ndarray, table: np.ndarray, name: str) -> np.ndarray:
        """The slot ``name`` of ``buf`` with its declared shape (a view)."""
        k = int(self.slot[name])
        at, ndim = int(table[k, 0]), len(self.shapes[name])
        return carve(buf, at, tuple(int(x) for x in table[k, 1:1 + ndim]))


def carve(buf, at, shape):
    """The C-contiguous block of the 1-D ``buf`` at offset ``at`` with ``shape``: a view.

    In compiled code this is an intrinsic that fills in the array's shape and strides directly,
    a few instructions. numba's ``reshape`` (numba/np/arrayobj.py, ``array_reshape``) calls the C
    helper ``numba_attempt_nocopy_reshape``, which LLVM cannot inline, and a view that shares
    buf's meminfo costs an atomic reference count up and down: together ~35 ns a view, and a
    filter step carves a few hundred, more than its arithmetic costs.
    The compiled view is therefore *borrowed*: no meminfo, valid while the caller holds ``buf``
    (every :class:`Layout` buffer is the Python caller's, alive for the whole kernel call), and
    never handed back to Python. The caller owns the bounds: a :class:`Layout` table's slots lie
    inside its buffer by construction."""
    return buf[at:at + math.prod(shape)].reshape(shape)


if HAVE_NUMBA:
    from numba.core import cgutils, types
    from numba.extending import intrinsic, overload
    from numba.np.arrayobj import make_array, populate_array

    @intrinsic
    def _carve(typingctx, buf, at, shape):
        """``carve`` as machine code: the view's data pointer is buf's plus ``at`` elements, its
        strides C order, no meminfo or parent (borrowed, as ``numba.carray``'s arrays are)."""
        if not (isinstance(buf, types.Array) and buf.ndim == 1 and buf.layout == "C"
                and isinstance(at, types.Integer) and isinstance(shape, types.UniTuple)
                and isinstance(shape.dtype, types.Integer)):
            return None
        out = types.Array(buf.dtype, shape.count, "C")

        def codegen(context, builder, sig, args):
            src = make_array(sig.args[0])(context, builder, args[0])
            intp = context.get_value_type(types.intp)
            dims = [builder.sext(d, intp) if d.type.width < intp.width else d
                    for d in cgutils.unpack_tuple(builder, args[2])]
            itemsize = context.get_constant(types.intp, context.get_abi_sizeof(context.get_data_type(buf.dtype)))
            strides, acc = [], itemsize
            for d in reversed(dims):
                strides.insert(0, acc)
                acc = builder.mul(acc, d)
            offset = builder.sext(args[1], intp) if args[1].type.width < intp.width else args[1]
            view = make_array(out)(context, builder)
            populate_array(view, data=builder.gep(src.data, [offset]), shape=dims, strides=strides,
                           itemsize=itemsize, meminfo=None, parent=None)
            return view._getvalue()

        return out(buf, at, shape), codegen

    @overload(carve, jit_options={"cache": True})
    def _carve_overload(buf, at, shape):
        return lambda buf, at, shape: _carve(buf, at, shape)


@jit
def view1(buf, table, k):
    """Slot k of a flat buffer (:class:`Layout`), 1-D."""
    return carve(buf, table[k, 0], (table[k, 1],))


@jit
def view2(buf, table, k):
    """Slot k of a flat buffer (:class:`Layout`), 2-D."""
    return carve(buf, table[k, 0], (table[k, 1], table[k, 2]))


@jit
def view3(buf, table, k):
    """Slot k of a flat buffer (:class:`Layout`), 3-D."""
    return carve(buf, table[k, 0], (table[k, 1], table[k, 2], table[k, 3]))


