"""Host functions called from jitted JAX programs that the persistent compilation cache can keep.

`jax.pure_callback` would do the job, but JAX never writes a program with a Python callback to
its persistent compilation cache (`jax/_src/compiler.py`, `_cache_write`: "uses host callbacks"):
the callback is a Python object that a later process cannot find again. With MuJoCo C physics
in every env step, that would rule out the cache for every training, eval and render program.

This module registers one XLA FFI target, `vnl_host_call`, whose handler is a C function made by
`ctypes` from Python: it reads the call's buffers and an integer attribute `key`, and calls the
host function registered under that key with numpy views of the input and output buffers. A
program refers to its host function by `key` only, so a compiled program is a pure function of
its HLO and can be cached; a key is derived from what the function computes (e.g. a hash of the
MuJoCo model), so the same env built in a later process registers the same key before running
the cached program.

The handler follows XLA's FFI C API (`jaxlib/include/xla/ffi/api/c_api.h`, API 0.2): it answers
the metadata query XLA sends at registration, runs only in the execute stage, and reports a
Python exception as an XLA error (`XLA_FFI_Error_Create`), which JAX raises as a runtime error.
The exception itself is kept (`vnl.errors.keep`) under a token the message carries, so the CLI
reports what the host function raised (`vnl.errors.original`): a `VnlError`, no memory, a
storage error as one line; anything else with its own traceback.
On other platforms (a GPU) `call` falls back to `jax.pure_callback`.
"""

from __future__ import annotations

import ctypes
import threading
import traceback
from collections.abc import Callable, Sequence
from typing import Any

import jax
import numpy as np

from vnl import errors

TARGET = "vnl_host_call"
HostFn = Callable[[list[np.ndarray], list[np.ndarray]], None]
"""`fn(inputs, outputs)`: reads the input arrays, writes every output array in place."""

_REGISTRY: dict[int, HostFn] = {}
_LOCK = threading.Lock()
_registered = False

# --- the C API's structs (c_api.h), as ctypes sees them --------------------------------------
_API_MAJOR, _API_MINOR = 0, 2
_EXTENSION_METADATA = 1
_STAGE_EXECUTE = 3
_ATTR_SCALAR = 3
_ERROR_INTERNAL = 13
_DTYPES = {
    1: np.bool_,
    2: np.int8,
    3: np.int16,
    4: np.int32,
    5: np.int64,
    6: np.uint8,
    7: np.uint16,
    8: np.uint32,
    9: np.uint64,
    10: np.float16,
    11: np.float32,
    12: np.float64,
}


class _ExtensionBase(ctypes.Structure):
    _fields_ = [("struct_size", ctypes.c_size_t), ("type", ctypes.c_int), ("next", ctypes.c_void_p)]


class _ApiVersion(ctypes.Structure):
    _fields_ = [
        ("struct_size", ctypes.c_size_t),
        ("extension_start", ctypes.c_void_p),
        ("major_version", ctypes.c_int),
        ("minor_version", ctypes.c_int),
    ]


class _Metadata(ctypes.Structure):
    _fields_ = [
        ("struct_size", ctypes.c_size_t),
        ("api_version", _ApiVersion),
        ("traits", ctypes.c_uint32),
        ("state_type_id", ctypes.c_int64),
    ]


class _MetadataExtension(ctypes.Structure):
    _fields_ = [("extension_base", _ExtensionBase), ("metadata", ctypes.POINTER(_Metadata))]


class _Buffer(ctypes.Structure):
    _fields_ = [
        ("struct_size", ctypes.c_size_t),
        ("extension_start", ctypes.c_void_p),
        ("dtype", ctypes.c_int),
        ("data", ctypes.c_void_p),
        ("rank", ctypes.c_int64),
        ("dims", ctypes.POINTER(ctypes.c_int64)),
    ]


class _List(ctypes.Structure):  # XLA_FFI_Args and XLA_FFI_Rets
    _fields_ = [
        ("struct_size", ctypes.c_size_t),
        ("extension_start", ctypes.c_void_p),
        ("size", ctypes.c_int64),
        ("types", ctypes.POINTER(ctypes.c_int)),
        ("items", ctypes.POINTER(ctypes.c_void_p)),
    ]


class _ByteSpan(ctypes.Structure):
    _fields_ = [("ptr", ctypes.c_void_p), ("len", ctypes.c_size_t)]


class _Attrs(ctypes.Structure):
    _fields_ = [
        ("struct_size", ctypes.c_size_t),
        ("extension_start", ctypes.c_void_p),
        ("size", ctypes.c_int64),
        ("types", ctypes.POINTER(ctypes.c_int)),
        ("names", ctypes.POINTER(ctypes.POINTER(_ByteSpan))),
        ("attrs", ctypes.POINTER(ctypes.c_void_p)),
    ]


class _Scalar(ctypes.Structure):
    _fields_ = [("dtype", ctypes.c_int), ("value", ctypes.c_void_p)]


class _CallFrame(ctypes.Structure):
    _fields_ = [
        ("struct_size", ctypes.c_size_t),
        ("extension_start", ctypes.POINTER(_ExtensionBase)),
        ("api", ctypes.c_void_p),
        ("ctx", ctypes.c_void_p),
        ("stage", ctypes.c_int),
        ("args", _List),
        ("rets", _List),
        ("attrs", _Attrs),
        ("future", ctypes.c_void_p),
    ]


class _ErrorCreateArgs(ctypes.Structure):
    _fields_ = [
        ("struct_size", ctypes.c_size_t),
        ("extension_start", ctypes.c_void_p),
        ("message", ctypes.c_char_p),
        ("errc", ctypes.c_int),
    ]


class _Api(ctypes.Structure):  # the leading fields of XLA_FFI_Api, up to XLA_FFI_Error_Create
    _fields_ = [
        ("struct_size", ctypes.c_size_t),
        ("extension_start", ctypes.c_void_p),
        ("api_version", _ApiVersion),
        ("internal_api", ctypes.c_void_p),
        ("error_create", ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.POINTER(_ErrorCreateArgs))),
    ]


_HANDLER_TYPE = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.POINTER(_CallFrame))


def _array(buffer_ptr: int) -> np.ndarray:
    """A numpy view (no copy) of an XLA_FFI_Buffer."""
    b = _Buffer.from_address(buffer_ptr)
    shape = tuple(b.dims[i] for i in range(b.rank))
    dtype = np.dtype(_DTYPES[b.dtype])
    n = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    if n == 0:
        return np.empty(shape, dtype)
    raw = (ctypes.c_char * n).from_address(b.data)
    return np.frombuffer(raw, dtype=dtype).reshape(shape)


def _key(attrs: _Attrs) -> int:
    for i in range(attrs.size):
        span = attrs.names[i].contents
        if ctypes.string_at(span.ptr, span.len) == b"key" and attrs.types[i] == _ATTR_SCALAR:
            scalar = _Scalar.from_address(attrs.attrs[i])
            return ctypes.c_int64.from_address(scalar.value).value
    raise RuntimeError(f"{TARGET}: the call has no integer attribute 'key'")


def _error(frame: _CallFrame, message: str) -> int | None:
    api = _Api.from_address(frame.api)
    args = _ErrorCreateArgs(ctypes.sizeof(_ErrorCreateArgs), None, message.encode()[:4000], _ERROR_INTERNAL)
    return api.error_create(ctypes.byref(args))


def _handle(frame_ptr: Any) -> int | None:
    """The FFI handler: metadata query, or one call of a registered host function."""
    frame = frame_ptr.contents
    ext = frame.extension_start
    if ext and ext.contents.type == _EXTENSION_METADATA:
        meta = ctypes.cast(ext, ctypes.POINTER(_MetadataExtension)).contents.metadata.contents
        meta.api_version.major_version = _API_MAJOR
        meta.api_version.minor_version = _API_MINOR
        meta.traits = 0
        return None
    if frame.stage != _STAGE_EXECUTE:
        return None
    try:
        fn = _REGISTRY[_key(frame.attrs)]
        inputs = [_array(frame.args.items[i]) for i in range(frame.args.size)]
        outputs = [_array(frame.rets.items[i]) for i in range(frame.rets.size)]
        fn(inputs, outputs)
        return None
    except BaseException as e:  # an exception must not cross into XLA's C++ frames
        tag = errors.keep(e)
        return _error(frame, f"{TARGET}: {tag} {type(e).__name__}: {e}\n{traceback.format_exc(limit=4)}")


_HANDLER = _HANDLER_TYPE(_handle)  # kept alive for the life of the process


def _ensure_target() -> None:
    global _registered
    with _LOCK:
        if not _registered:
            capsule = jax.ffi.pycapsule(ctypes.cast(_HANDLER, ctypes.c_void_p).value)
            jax.ffi.register_ffi_target(TARGET, capsule, platform="cpu", api_version=1)
            _registered = True


def register(key: int, fn: HostFn) -> int:
    """Makes `fn` callable from programs as `key` (63 bits); returns the key."""
    key = int(key) & 0x7FFF_FFFF_FFFF_FFFF
    _REGISTRY[key] = fn
    return key


def call(key: int, results: Sequence[jax.ShapeDtypeStruct], *args: jax.Array) -> list[jax.Array]:
    """Calls the host function `key` from a traced program: returns arrays shaped as `results`.

    Under `vmap` the host function sees every input and output with the batch axes in front
    (`broadcast_all`): one call per batch, not per element. On the CPU backend this is an FFI
    call (cacheable); elsewhere a `jax.pure_callback` (the data go through host memory anyway).
    """
    if jax.default_backend() == "cpu":
        _ensure_target()
        out = jax.ffi.ffi_call(TARGET, list(results), vmap_method="broadcast_all")(*args, key=np.int64(key))
        return list(out)
    fn = _REGISTRY[key]
    rank = len(np.shape(args[0]))  # the first input's rank without batch axes (as traced)

    def host(*arrays: np.ndarray) -> list[np.ndarray]:
        batch = arrays[0].shape[: arrays[0].ndim - rank]
        outputs = [np.empty(tuple(batch) + tuple(r.shape), r.dtype) for r in results]
        try:
            fn([np.asarray(a) for a in arrays], outputs)
        except BaseException as e:  # noqa: BLE001 - kept for the CLI, as for the FFI handler
            raise RuntimeError(f"{TARGET}: {errors.keep(e)} {type(e).__name__}: {e}") from e
        return outputs

    return list(jax.pure_callback(host, list(results), *args, vmap_method="broadcast_all"))
