"""Typed records across the Python -> numba boundary as one float64 array.

Inside the kernels a contribution's state is a named tuple of arrays and scalars. numba 0.59 (Ubuntu 24.04's) types a
tuple argument in Python on every call from Python (10-60 us), an array in C: so a state crosses the boundary packed
into one float64 array. ``put`` appends a field (a scalar: its value; an array: its shape, then its values), the
``take_*`` functions read one back in the same order as a fresh array of the field's type; ``cursor`` (an int64 array of
one element) is the read or write position. A first pass over an empty buffer only counts (``pack_record``).
"""
from __future__ import annotations

import numpy as np
from numba import njit, types
from numba.extending import overload


def compiled_entry(dispatcher, *arguments):
    """The compiled function of the numba ``dispatcher`` for the types of ``arguments`` (compiled or loaded now if
    new): no typing per call, so only for values of these types (its wrapper unboxes them as such, unchecked)."""
    return dispatcher.compile(tuple(map(dispatcher.typeof_pyval, arguments)))


def put(buffer, cursor, value):
    """Append ``value`` (scalar, 1-d or 2-d array) at cursor[0] (only counted if ``buffer`` is empty)."""
    raise NotImplementedError("put runs compiled only")


@overload(put)
def _put(buffer, cursor, value):
    if isinstance(value, types.Array) and value.ndim == 1:
        def put_vector(buffer, cursor, value):
            start = cursor[0]
            if buffer.size:
                buffer[start] = value.size
                for i in range(value.size):
                    buffer[start + 1 + i] = value[i]
            cursor[0] = start + 1 + value.size
        return put_vector
    if isinstance(value, types.Array) and value.ndim == 2:
        def put_matrix(buffer, cursor, value):
            start = cursor[0]
            rows, columns = value.shape
            if buffer.size:
                buffer[start], buffer[start + 1] = rows, columns
                for i in range(rows):
                    for j in range(columns):
                        buffer[start + 2 + i * columns + j] = value[i, j]
            cursor[0] = start + 2 + rows * columns
        return put_matrix
    if isinstance(value, (types.Float, types.Integer, types.Boolean)):
        def put_scalar(buffer, cursor, value):
            if buffer.size:
                buffer[cursor[0]] = value
            cursor[0] += 1
        return put_scalar
    return None


@njit(cache=True)
def take_float(buffer, cursor):
    cursor[0] += 1
    return buffer[cursor[0] - 1]


@njit(cache=True)
def take_int(buffer, cursor):
    return int(take_float(buffer, cursor))


@njit(cache=True)
def take_flag(buffer, cursor):
    return take_float(buffer, cursor) != 0.0


@njit(cache=True)
def view_vector(buffer, cursor):
    """A 1-d field as a view into ``buffer`` (constants: never written)."""
    size = int(buffer[cursor[0]])
    start = cursor[0] + 1
    cursor[0] = start + size
    return buffer[start:start + size]


@njit(cache=True)
def view_matrix(buffer, cursor):
    """A 2-d field as a view into ``buffer`` (constants: never written)."""
    rows, columns = int(buffer[cursor[0]]), int(buffer[cursor[0] + 1])
    start = cursor[0] + 2
    cursor[0] = start + rows * columns
    return buffer[start:start + rows * columns].reshape((rows, columns))


@njit(cache=True)
def take_vector(buffer, cursor):
    return view_vector(buffer, cursor).copy()


@njit(cache=True)
def take_matrix(buffer, cursor):
    return view_matrix(buffer, cursor).copy()


@njit(cache=True)
def take_index_matrix(buffer, cursor):
    return take_matrix(buffer, cursor).astype(np.int64)


@njit(cache=True)
def take_flags(buffer, cursor):
    return take_vector(buffer, cursor) != 0.0


def put_all(buffer, cursor, fields):
    """``put`` each of a tuple's fields in order."""
    raise NotImplementedError("put_all runs compiled only")


@overload(put_all)
def _put_all(buffer, cursor, fields):
    if not isinstance(fields, types.BaseTuple):
        return None
    # one ``put`` per field in straight-line code: ``literal_unroll`` over a mixed tuple cost ~70 ns per field
    source = "def put_fields(buffer, cursor, fields):\n    pass\n" + "".join(
        f"    put(buffer, cursor, fields[{i}])\n" for i in range(len(fields)))
    scope = {"put": put}
    exec(source, scope)
    return scope["put_fields"]


@njit(cache=True)
def _put_record(buffer, record):
    cursor = np.zeros(1, dtype=np.int64)
    put_all(buffer, cursor, record)
    return cursor[0]


@njit(cache=True)
def pack_record(record):
    """A contribution's typed record (a named tuple: the tissue's ``ContactRecord``, ``ShaftRecord``) as one
    float64 array in ``put``'s layout (compiled: the kernels' own records; :func:`packed` from Python)."""
    buffer = np.empty(_put_record(np.empty(0), record))
    _put_record(buffer, record)
    return buffer


def packed(*fields) -> np.ndarray:
    """The fields (scalars, 1-d and 2-d arrays) as one float64 array in ``put``'s layout (from Python)."""
    chunks = []
    for field in fields:
        array = np.asarray(field, dtype=float)
        chunks += [array.reshape(1)] if array.ndim == 0 else [np.array(array.shape, dtype=float), array.ravel()]
    return np.concatenate(chunks) if chunks else np.zeros(0)
