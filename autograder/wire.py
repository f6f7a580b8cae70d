"""The wire format between the grader and the sandboxed child that runs a submission.

Frames (``MAGIC, len(header), len(payload)``, then a JSON header and raw array
bytes: :func:`pack_frame`, :func:`parse_frame`), call arguments
(:func:`encode_args` in the grader, :func:`decode_args` in the child, with
:class:`RngSeed` for a generator argument) and return values
(:func:`encode_result` in the child, :func:`decode_result` in the grader, which
rebuilds :class:`Returned` / :class:`Value`). No pickles: every descriptor is
validated when it is read, and a malformed one raises :class:`ProtocolError`.

Both sides import this module: the grader as ``autograder.wire``, the child
(``_runner.py``, run as a script in the sandbox) by its path before it isolates
itself. It imports only the standard library; NumPy is passed in as ``np`` by the
caller, so the child loads it when it chooses to, and nothing here touches
``slamlib``.
"""

from __future__ import annotations

import json
import re
import struct

__all__ = ["MAGIC", "MAX_HEADER", "MAX_PAYLOAD", "MAX_ITEMS", "MAX_RESULT_BYTES", "ProtocolError", "pack_frame",
           "parse_frame", "encode_args", "RngSeed", "decode_args", "encode_result", "Value", "Returned",
           "describe_value", "decode_result", "shorten"]

# this module's own references, taken when it is loaded, before any submission code runs (a submission that
# monkeypatches json does not change what the wire format calls)
_dumps, _loads = json.dumps, json.loads

MAGIC = b"AGW1"
_HDR = struct.Struct("<4sII")
MAX_HEADER = 1 << 20  # bytes of JSON per frame
MAX_PAYLOAD = 256 << 20  # bytes of array data per frame
MAX_ITEMS = 16  # items of a returned tuple that are encoded
MAX_RESULT_BYTES = 64 << 20
_DTYPE_RE = re.compile(r"^[<>|=]?[biufc][0-9]{1,2}$")
_DTYPE_KINDS = "biufc"


class ProtocolError(Exception):
    """A frame or a descriptor that does not follow the wire format."""


# --------------------------------------------------------------------------- frames
def pack_frame(header, payload=b""):
    """Serialise one frame: magic, lengths, JSON header, payload bytes."""
    h = _dumps(header, allow_nan=True, separators=(",", ":")).encode("utf-8")
    return _HDR.pack(MAGIC, len(h), len(payload)) + h + payload


def parse_frame(buf):
    """Parse one frame at the start of ``buf`` (bytes-like).

    Returns ``(header, payload, consumed)`` or ``None`` when ``buf`` does not yet
    hold a whole frame. Raises :class:`ProtocolError` on malformed input.
    """
    if len(buf) < _HDR.size:
        return None
    magic, hl, pl = _HDR.unpack_from(buf, 0)
    if magic != MAGIC:
        raise ProtocolError("bad frame magic")
    if hl > MAX_HEADER or pl > MAX_PAYLOAD:
        raise ProtocolError("frame too large")
    end = _HDR.size + hl + pl
    if len(buf) < end:
        return None
    try:
        header = _loads(bytes(buf[_HDR.size:_HDR.size + hl]).decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise ProtocolError(f"bad frame header: {exc}") from None
    if not isinstance(header, dict):
        raise ProtocolError("frame header is not an object")
    return header, bytes(buf[_HDR.size + hl:end]), end


# --------------------------------------------------------------------------- arrays
def _array_desc(a, parts, offset):
    """Describe contiguous array ``a`` whose bytes are appended to ``parts``."""
    data = a.tobytes()
    parts.append(data)
    return {"t": "arr", "dtype": a.dtype.str, "shape": [int(s) for s in a.shape], "off": offset, "len": len(data)}


def _read_array(desc, payload, np):
    """Rebuild a plain ndarray from a descriptor, validating everything."""
    dtype = desc.get("dtype")
    shape = desc.get("shape")
    off = desc.get("off")
    ln = desc.get("len")
    if not (isinstance(dtype, str) and _DTYPE_RE.match(dtype)):
        raise ProtocolError(f"unsupported dtype {dtype!r}")
    if not (isinstance(shape, list) and len(shape) <= 32 and all(type(s) is int and 0 <= s for s in shape)):
        raise ProtocolError("bad shape")
    if not (type(off) is int and type(ln) is int and 0 <= off and 0 <= ln and off + ln <= len(payload)):
        raise ProtocolError("bad array extent")
    try:
        dt = np.dtype(dtype)
    except TypeError:
        raise ProtocolError(f"unsupported dtype {dtype!r}") from None
    if dt.kind not in _DTYPE_KINDS or dt.hasobject:
        raise ProtocolError(f"unsupported dtype {dtype!r}")
    n = 1
    for s in shape:
        n *= s
    if n * dt.itemsize != ln:
        raise ProtocolError("array size does not match its shape")
    arr = np.frombuffer(payload, dtype=dt, count=n, offset=off).reshape(shape)
    return np.array(arr, copy=True)


# --------------------------------------------------------------------------- arguments (parent -> child)
def encode_args(args, kwargs, np):
    """Encode call arguments: float/int arrays, numbers, None, booleans, seeds.

    An argument ``{"rng": seed}`` (see :class:`RngSeed`) becomes
    ``numpy.random.default_rng(seed)`` in the callee.
    """
    parts = []
    size = [0]

    def enc(v):
        if isinstance(v, RngSeed):
            return {"t": "rng", "seed": int(v.seed)}
        if v is None:
            return {"t": "none"}
        if isinstance(v, (bool, np.bool_)):
            return {"t": "bool", "v": bool(v)}
        if isinstance(v, (int, np.integer)):
            return {"t": "int", "v": int(v)}
        if isinstance(v, (float, np.floating)):
            return {"t": "float", "v": float(v)}
        if isinstance(v, np.ndarray):
            a = np.array(v, order="C", copy=True)
            if a.dtype.kind not in "iuf":
                raise TypeError(f"cannot send dtype {a.dtype}")
            d = _array_desc(a, parts, size[0])
            size[0] += d["len"]
            return d
        raise TypeError(f"cannot send {type(v).__name__}")

    header = {"args": [enc(a) for a in args], "kwargs": {k: enc(v) for k, v in kwargs.items()}}
    return header, b"".join(parts)


class RngSeed:
    """Marks an argument that the callee receives as ``default_rng(seed)``."""

    __slots__ = ("seed",)

    def __init__(self, seed):
        self.seed = int(seed)

    def __repr__(self):
        return f"np.random.default_rng({self.seed})"


def decode_args(header, payload, np):
    """Child side of :func:`encode_args`."""

    def dec(d):
        t = d.get("t")
        if t == "rng":
            return np.random.default_rng(int(d["seed"]))
        if t == "none":
            return None
        if t in ("bool", "int", "float"):
            return {"bool": bool, "int": int, "float": float}[t](d["v"])
        if t == "arr":
            return _read_array(d, payload, np)
        raise ProtocolError(f"unknown argument type {t!r}")

    args = [dec(d) for d in header.get("args", [])]
    kwargs = {str(k): dec(d) for k, d in header.get("kwargs", {}).items()}
    return args, kwargs


# --------------------------------------------------------------------------- results (child -> parent)
def shorten(text, n=300):
    """``text`` cut to ``n`` characters (an ellipsis marks the cut)."""
    text = str(text)
    return text if len(text) <= n else text[: n - 3] + "..."


def _encode_item(obj, parts, size, np):
    info = {}
    try:
        info["py"] = shorten(type(obj).__name__, 60)
        info["int_like"] = bool(isinstance(obj, (int, np.integer)) and not isinstance(obj, (bool, np.bool_)))
        info["subclass"] = (shorten(type(obj).__name__, 60)
                            if isinstance(obj, np.ndarray) and type(obj) is not np.ndarray else None)
        if str(getattr(type(obj), "__module__", "")).startswith("scipy.sparse") and hasattr(obj, "toarray"):
            obj = obj.toarray()  # a scipy.sparse matrix (build_linear_system may return one) is judged densely
        a = np.asarray(obj)
        if type(a) is not np.ndarray:
            a = a.view(np.ndarray)
    except BaseException as exc:  # a hostile __array__ or __class__
        return {"t": "bad", "why": shorten(f"numpy.asarray() failed on the result: {type(exc).__name__}: {exc}"), **info}
    if a.dtype.kind not in _DTYPE_KINDS or a.dtype.hasobject or a.dtype.names is not None:
        return {"t": "bad", "why": shorten(f"numpy.asarray() of the result has dtype {a.dtype}"),
                "dtype_kind": a.dtype.kind, "shape": [int(s) for s in a.shape], **info}
    if a.nbytes + size[0] > MAX_RESULT_BYTES:
        return {"t": "bad", "why": f"the result is too large ({a.nbytes} bytes)", **info}
    a = np.array(a, order="C", copy=True)
    if a.dtype.byteorder == ">":
        a = a.astype(a.dtype.newbyteorder("<"))
    d = _array_desc(a, parts, size[0])
    size[0] += d["len"]
    d.update(info)
    return d


def encode_result(obj, np):
    """Encode a function's return value as plain arrays.

    A top-level tuple or list is encoded item by item (for functions returning
    several results) and also as a whole (``numpy.asarray(result)``, for
    functions returning one array that a student built as a list).
    """
    parts = []
    size = [0]
    if isinstance(obj, (tuple, list)):
        try:
            n = len(obj)
            items = [_encode_item(o, parts, size, np) for o in list(obj)[:MAX_ITEMS]]
        except BaseException as exc:
            return {"t": "item", "value": {"t": "bad", "why": shorten(f"could not read the result: {exc}")}}, b""
        whole = _encode_item(obj, parts, size, np)
        desc = {"t": "seq", "kind": "tuple" if isinstance(obj, tuple) else "list", "n": n, "items": items,
                "whole": whole}
    else:
        desc = {"t": "item", "value": _encode_item(obj, parts, size, np)}
    return desc, b"".join(parts)


class Value:
    """One returned value, as the grader sees it after decoding.

    Attributes
    ----------
    array : ndarray or None
        ``numpy.asarray(value)`` as a plain array (None if it could not be built).
    problem : str or None
        Why no usable array exists (object dtype, failing ``__array__`` ...).
    py : str
        Type name of the object the function returned.
    int_like : bool
        Whether it was a Python ``int`` or a NumPy integer.
    subclass : str or None
        Name of the ndarray subclass returned, if any.
    """

    __slots__ = ("array", "problem", "py", "int_like", "subclass", "dtype_kind", "shape")

    def __init__(self, array=None, problem=None, py="?", int_like=False, subclass=None, dtype_kind=None, shape=None):
        self.array = array
        self.problem = problem
        self.py = py
        self.int_like = int_like
        self.subclass = subclass
        self.dtype_kind = dtype_kind if array is None else array.dtype.kind
        self.shape = tuple(shape) if (shape is not None and array is None) else (None if array is None else array.shape)


class Returned:
    """A decoded return value: a sequence of :class:`Value` or a single one."""

    __slots__ = ("seq_kind", "n", "items", "whole", "value")

    def __init__(self, seq_kind=None, n=0, items=(), whole=None, value=None):
        self.seq_kind = seq_kind  # "tuple", "list" or None for a single value
        self.n = n
        self.items = list(items)
        self.whole = whole
        self.value = value

    def describe(self):
        if self.seq_kind is None:
            return describe_value(self.value)
        return f"a {self.seq_kind} of {self.n} item{'s' if self.n != 1 else ''}"


def describe_value(v):
    if v.array is None:
        return f"a {v.py} ({v.problem})"
    a = v.array
    kind = {"b": "bool", "i": "int", "u": "unsigned int", "f": "float", "c": "complex"}.get(a.dtype.kind, str(a.dtype))
    if a.ndim == 0:
        return f"a {v.py} ({kind})"
    return f"a {v.py} of shape {a.shape} and dtype {a.dtype} ({kind})"


def _decode_item(d, payload, np):
    if not isinstance(d, dict):
        raise ProtocolError("bad value descriptor")
    py = d.get("py", "?")
    py = py if isinstance(py, str) else "?"
    int_like = d.get("int_like") is True
    sub = d.get("subclass")
    sub = sub if isinstance(sub, str) else None
    if d.get("t") == "arr":
        return Value(_read_array(d, payload, np), None, py[:60], int_like, sub)
    if d.get("t") == "bad":
        why = d.get("why")
        kind = d.get("dtype_kind") if isinstance(d.get("dtype_kind"), str) else None
        shape = d.get("shape")
        shape = shape if (isinstance(shape, list) and all(type(s) is int for s in shape)) else None
        return Value(None, shorten(why if isinstance(why, str) else "unreadable result"), py[:60], int_like, sub,
                     kind, shape)
    raise ProtocolError("bad value descriptor")


def decode_result(desc, payload, np):
    """Parent side of :func:`encode_result`; raises ProtocolError on bad input."""
    if not isinstance(desc, dict):
        raise ProtocolError("bad result descriptor")
    if desc.get("t") == "item":
        return Returned(value=_decode_item(desc.get("value"), payload, np))
    if desc.get("t") == "seq":
        items = desc.get("items")
        n = desc.get("n")
        kind = desc.get("kind")
        if not (isinstance(items, list) and type(n) is int and n >= 0 and kind in ("tuple", "list")):
            raise ProtocolError("bad sequence descriptor")
        if len(items) > MAX_ITEMS:
            raise ProtocolError("too many items")
        return Returned(kind, n, [_decode_item(i, payload, np) for i in items],
                        _decode_item(desc.get("whole"), payload, np))
    raise ProtocolError("bad result descriptor")
