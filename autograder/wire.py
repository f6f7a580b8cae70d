"""The wire format between the grader and the sandboxed child that runs a submission.

Frames (``MAGIC, len(header), len(payload)``, then a JSON header and raw array
bytes: :func:`pack_frame`, :func:`parse_frame`), call arguments
(:func:`encode_args` in the grader, :func:`decode_args` in the child, with
:class:`RngSeed` for a generator argument) and return values
(:func:`encode_result` in the child, :func:`decode_result` in the grader, which
rebuilds :class:`Returned` / :class:`Value`). No pickles: every descriptor is
validated when it is read, and a malformed one raises :class:`ProtocolError`.

Everything the grader reads from the child is untrusted (the child runs the
submission's code) and goes through one validating parser: :func:`parse_result_frame`
and :func:`read_reply` for a worker's result frames, :func:`control_message` for the
control socket. JSON is checked for size, nesting depth (:data:`MAX_DEPTH`, so a
deeply nested message is refused, never a ``RecursionError``), finite numbers and
its schema (types, lengths); array extents may neither overlap nor repeat, and the
bytes decoded per frame are capped (:data:`MAX_RESULT_BYTES`) and decoded before the
call's deadline. A message that fails any check raises :class:`ProtocolError`, which
costs the function that sent it its points, never the grading.

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
import sys as _sys
import time as _time

__all__ = ["MAGIC", "MAX_HEADER", "MAX_PAYLOAD", "MAX_ITEMS", "MAX_RESULT_BYTES", "ProtocolError", "pack_frame",
           "parse_frame", "encode_args", "RngSeed", "decode_args", "encode_result", "Value", "Returned",
           "describe_value", "decode_result", "shorten", "MAX_DEPTH", "MAX_JOB", "loads_untrusted",
           "parse_result_frame", "read_reply", "control_message", "is_sparse", "clean_text"]

# this module's own references, taken when it is loaded, before any submission code runs (a submission that
# monkeypatches json does not change what the wire format calls)
_dumps, _loads = json.dumps, json.loads
_monotonic = _time.monotonic

MAGIC = b"AGW1"
_HDR = struct.Struct("<4sII")
MAX_HEADER = 1 << 20  # bytes of JSON per frame
MAX_PAYLOAD = 256 << 20  # bytes of array data per frame
MAX_ITEMS = 16  # items of a returned tuple that are encoded
MAX_RESULT_BYTES = 64 << 20  # bytes of array data in one result (encoded by the child, decoded by the grader)
MAX_JOB = 64 << 20  # bytes of JSON in the job (grader -> child: the submission's sources; trusted)
MAX_DEPTH = 12  # nesting of any JSON value
MAX_CONTROL = 1 << 20  # bytes of one control message
_DTYPE_RE = re.compile(r"^[<>|=]?[biufc][0-9]{1,2}$")
_DTYPE_KINDS = "biufc"


class ProtocolError(Exception):
    """A frame or a descriptor that does not follow the wire format."""


# --------------------------------------------------------------------------- frames
def pack_frame(header, payload=b""):
    """Serialise one frame: magic, lengths, JSON header, payload bytes."""
    h = _dumps(header, allow_nan=True, separators=(",", ":")).encode("utf-8")
    return _HDR.pack(MAGIC, len(h), len(payload)) + h + payload


def parse_frame(buf, *, max_header=MAX_HEADER, max_payload=MAX_PAYLOAD, finite=False, clean=False):
    """Parse one frame at the start of ``buf`` (bytes-like).

    Returns ``(header, payload, consumed)`` or ``None`` when ``buf`` does not yet
    hold a whole frame. Raises :class:`ProtocolError` on malformed input: bad magic,
    lengths above ``max_header`` / ``max_payload``, a header that is not a JSON
    object or nests deeper than :data:`MAX_DEPTH`, and (``finite``) a non-finite
    number in the header. ``clean``: every string of the header through :func:`clean_text`.
    """
    if len(buf) < _HDR.size:
        return None
    magic, hl, pl = _HDR.unpack_from(buf, 0)
    if magic != MAGIC:
        raise ProtocolError("bad frame magic")
    if hl > max_header or pl > max_payload:
        raise ProtocolError("frame too large")
    end = _HDR.size + hl + pl
    if len(buf) < end:
        return None
    header = loads_untrusted(bytes(buf[_HDR.size:_HDR.size + hl]), max_bytes=max_header, finite=finite, clean=clean)
    if not isinstance(header, dict):
        raise ProtocolError("frame header is not an object")
    return header, bytes(buf[_HDR.size + hl:end]), end


def parse_result_frame(buf):
    """A worker's result frame (child -> grader): :func:`parse_frame` with the result's caps, finite numbers only."""
    return parse_frame(buf, max_header=MAX_HEADER, max_payload=MAX_RESULT_BYTES, finite=True, clean=True)


# --------------------------------------------------------------------------- untrusted JSON
def _no_constant(name):
    raise ProtocolError(f"non-finite number {name} in a message")


def _finite_float(text):
    v = float(text)
    if v != v or v in (float("inf"), float("-inf")):
        raise ProtocolError("non-finite number in a message")
    return v


_UNSAFE = re.compile(r"[\x00-\x08\x0b-\x1f\x7f-\x9f\ud800-\udfff]")


def clean_text(text):
    """``text`` with control characters (but newline and tab) and lone surrogates written as escapes.

    Text the submission chose (an exception's message, its output, a file name it set) is printed in
    the grader's terminal and written to results.json and the CSV: an escape sequence could redraw the
    terminal (a forged total), and a lone surrogate (valid in JSON's ``\\ud800``, not in UTF-8) fails
    every write.
    """
    text = str(text)
    if not _UNSAFE.search(text):
        return text
    return _UNSAFE.sub(lambda m: f"\\x{ord(m.group()):02x}" if ord(m.group()) < 0x100 else f"\\u{ord(m.group()):04x}",
                       text)


def _cleaned(obj):
    """Every string (keys too) of a parsed JSON value through :func:`clean_text` (depth already checked)."""
    if isinstance(obj, str):
        return clean_text(obj)
    if isinstance(obj, list):
        return [_cleaned(v) for v in obj]
    if isinstance(obj, dict):
        return {clean_text(k): _cleaned(v) for k, v in obj.items()}
    return obj


def loads_untrusted(data, *, max_bytes, max_depth=MAX_DEPTH, finite=True, clean=False):
    """JSON text (bytes) from an untrusted side, checked: size, UTF-8, depth, and (``finite``) finite numbers.

    ``clean``: every string through :func:`clean_text` (what the grader reads from the sandbox; not the
    job the sandbox reads, whose strings are the submission's code).

    Raises :class:`ProtocolError` for anything else (never ``RecursionError``,
    ``ValueError`` or ``UnicodeDecodeError``).
    """
    if len(data) > max_bytes:
        raise ProtocolError(f"message too large ({len(data)} bytes)")
    try:
        text = bytes(data).decode("utf-8")
    except UnicodeDecodeError:
        raise ProtocolError("message is not UTF-8") from None
    # nesting is checked before parsing: brackets outside strings, counted in C (no recursion, linear time)
    if text.count("[") + text.count("{") > max_depth and _depth(text) > max_depth:
        raise ProtocolError(f"message nested deeper than {max_depth} levels")
    kw = {"parse_constant": _no_constant, "parse_float": _finite_float} if finite else {}
    try:
        value = _loads(text, **kw)
    except ProtocolError:
        raise
    except (ValueError, RecursionError, TypeError) as exc:
        raise ProtocolError(f"bad message: {shorten(exc, 120)}") from None
    return _cleaned(value) if clean else value


_STRINGS = re.compile(r'"(?:[^"\\]|\\.)*"', re.S)
_OPEN_CLOSE = str.maketrans("", "", "".join(chr(c) for c in range(128) if chr(c) not in "[]{}"))


def _depth(text):
    """Greatest bracket nesting of JSON ``text`` outside strings."""
    brackets = _STRINGS.sub("", text)
    brackets = "".join(ch for ch in brackets if ch in "[]{}") if not brackets.isascii() else brackets.translate(
        _OPEN_CLOSE)
    depth = best = 0
    for ch in brackets:
        if ch in "[{":
            depth += 1
            if depth > best:
                best = depth
        else:
            depth -= 1
    return best


# --------------------------------------------------------------------------- arrays
def _array_desc(a, parts, offset):
    """Describe contiguous array ``a`` whose bytes are appended to ``parts``."""
    data = a.tobytes()
    parts.append(data)
    return {"t": "arr", "dtype": a.dtype.str, "shape": [int(s) for s in a.shape], "off": offset, "len": len(data)}


#: The largest dimension, and the largest element count, of an array read back from a worker.
_MAX_DIM = 2 ** 31


def _read_array(desc, payload, np):
    """Rebuild a plain ndarray from a descriptor, validating everything."""
    dtype = desc.get("dtype")
    shape = desc.get("shape")
    off = desc.get("off")
    ln = desc.get("len")
    if not (isinstance(dtype, str) and _DTYPE_RE.match(dtype)):
        raise ProtocolError(f"unsupported dtype {dtype!r}")
    if not (isinstance(shape, list) and len(shape) <= 32
            and all(type(s) is int and 0 <= s <= _MAX_DIM for s in shape)):
        raise ProtocolError("bad shape")
    if not (type(off) is int and type(ln) is int and 0 <= off and 0 <= ln and off + ln <= len(payload)):
        raise ProtocolError("bad array extent")
    try:
        dt = np.dtype(dtype)
    except TypeError:
        raise ProtocolError(f"unsupported dtype {dtype!r}") from None
    if dt.kind not in _DTYPE_KINDS or dt.hasobject:
        raise ProtocolError(f"unsupported dtype {dtype!r}")
    n = big = 1
    for s in shape:
        n *= s
        big *= max(s, 1)
    if big > _MAX_DIM:  # empty arrays included: numpy refuses shapes whose nonzero sizes overflow
        raise ProtocolError("array has too many elements")
    if n * dt.itemsize != ln:
        raise ProtocolError("array size does not match its shape")
    try:
        arr = np.frombuffer(payload, dtype=dt, count=n, offset=off).reshape(shape)
        return np.array(arr, copy=True)
    except (ValueError, TypeError, MemoryError, OverflowError) as exc:
        raise ProtocolError(f"bad array: {type(exc).__name__}") from None


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
        if is_sparse(obj):
            obj = obj.toarray()  # a scipy.sparse matrix or array, any subclass (build_linear_system may return one)
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


def _check_item(d):
    """Validate one value descriptor (no decoding); return its array extent ``(off, len)`` or None."""
    if not isinstance(d, dict):
        raise ProtocolError("bad value descriptor")
    for k in ("py", "subclass", "why", "dtype_kind"):
        if d.get(k) is not None and not isinstance(d.get(k), str):
            raise ProtocolError(f"bad value descriptor ({k})")
    if d.get("int_like") is not None and not isinstance(d.get("int_like"), bool):
        raise ProtocolError("bad value descriptor (int_like)")
    t = d.get("t")
    if t == "arr":
        off, ln = d.get("off"), d.get("len")
        if not (type(off) is int and type(ln) is int and off >= 0 and ln >= 0):
            raise ProtocolError("bad array extent")
        return off, ln
    if t == "bad":
        shape = d.get("shape")
        if shape is not None and not (isinstance(shape, list) and len(shape) <= 32
                                      and all(type(x) is int and 0 <= x < 2**63 for x in shape)):
            raise ProtocolError("bad value descriptor (shape)")
        return None
    raise ProtocolError("bad value descriptor")


def _plan(descs, payload_len):
    """Check that the arrays of a result use disjoint extents inside the payload, at most MAX_RESULT_BYTES in all."""
    extents = sorted(e for e in (_check_item(d) for d in descs) if e is not None and e[1] > 0)
    total, end = 0, 0
    for off, ln in extents:
        if off < end:
            raise ProtocolError("array extents overlap or repeat")
        end = off + ln
        total += ln
        if end > payload_len:
            raise ProtocolError("bad array extent")
    if total > MAX_RESULT_BYTES:
        raise ProtocolError(f"the result holds more than {MAX_RESULT_BYTES} bytes of arrays")


def _decode_item(d, payload, np, deadline=None):
    if deadline is not None and _monotonic() > deadline:
        raise ProtocolError("the result could not be decoded before the call's deadline")
    py = d.get("py", "?")
    py = py if isinstance(py, str) else "?"
    int_like = d.get("int_like") is True
    sub = d.get("subclass")
    sub = sub[:60] if isinstance(sub, str) else None
    if d.get("t") == "arr":
        return Value(_read_array(d, payload, np), None, py[:60], int_like, sub)
    why = d.get("why")
    kind = d.get("dtype_kind")[:1] if isinstance(d.get("dtype_kind"), str) else None
    return Value(None, shorten(why if isinstance(why, str) else "unreadable result"), py[:60], int_like, sub,
                 kind, d.get("shape"))


def decode_result(desc, payload, np, *, deadline=None):
    """Parent side of :func:`encode_result`; raises ProtocolError on bad input.

    Every descriptor is validated and the array extents are checked to be disjoint
    (each payload byte is decoded at most once, :data:`MAX_RESULT_BYTES` at most)
    before anything is decoded; ``deadline`` (a ``time.monotonic()`` value) stops the
    decoding when it is reached.
    """
    if not isinstance(desc, dict):
        raise ProtocolError("bad result descriptor")
    if desc.get("t") == "item":
        value = desc.get("value")
        _plan([value], len(payload))
        return Returned(value=_decode_item(value, payload, np, deadline))
    if desc.get("t") == "seq":
        items = desc.get("items")
        n = desc.get("n")
        kind = desc.get("kind")
        if not (isinstance(items, list) and type(n) is int and 0 <= n < 2**63 and kind in ("tuple", "list")):
            raise ProtocolError("bad sequence descriptor")
        if len(items) > MAX_ITEMS or len(items) > n:
            raise ProtocolError("too many items")
        whole = desc.get("whole")
        _plan(items + [whole], len(payload))
        return Returned(kind, n, [_decode_item(i, payload, np, deadline) for i in items],
                        _decode_item(whole, payload, np, deadline))
    raise ProtocolError("bad result descriptor")


# --------------------------------------------------------------------------- replies and control messages
def _text(v, n, what):
    if not isinstance(v, str):
        raise ProtocolError(f"{what} is not a string")
    return v[:n]


def _texts(v, n_items, n_chars, what):
    if v is None:
        return []
    if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
        raise ProtocolError(f"{what} is not a list of strings")
    return [x[:n_chars] for x in v[:n_items]]


def _number(v, what, low=0.0):
    if type(v) not in (int, float) or not (low <= v < 1e18):
        raise ProtocolError(f"{what} is not a number >= {low:g}")
    return float(v)


def read_reply(header, payload, np, *, deadline=None):
    """A worker's reply to one call, checked against its schema; the result decoded (:func:`decode_result`).

    Returns a dict with ``status`` (``"ok"``, ``"error"`` or ``"protocol"``),
    ``mutated``, ``blocked`` (lists of short strings), ``elapsed`` (seconds),
    ``error`` and ``where`` (strings) and ``returned`` (a :class:`Returned`, for
    ``"ok"``). Raises :class:`ProtocolError` for anything else.
    """
    if not isinstance(header, dict):
        raise ProtocolError("bad reply")
    st = header.get("status")
    if st not in ("ok", "error", "protocol"):
        raise ProtocolError(f"unexpected status {shorten(repr(st), 40)}")
    out = {
        "status": st,
        "mutated": _texts(header.get("mutated"), 10, 40, "mutated"),
        "blocked": _texts(header.get("blocked"), 20, 200, "blocked"),
        "elapsed": _number(header.get("elapsed") or 0.0, "elapsed"),
        "error": _text(header.get("error") if header.get("error") is not None else "", 2000, "error"),
        "where": _text(header.get("where") or "", 3000, "where"),
        "returned": None,
    }
    if st == "ok":
        out["returned"] = decode_result(header.get("result"), payload, np, deadline=deadline)
    return out


def _scalar_tree(v, depth, what):
    """A JSON value of the isolation report: scalars, strings, lists and objects, bounded in size and depth."""
    if v is None or isinstance(v, (bool, int)):
        return v
    if isinstance(v, float):
        if v != v or v in (float("inf"), float("-inf")):
            raise ProtocolError(f"{what}: non-finite number")
        return v
    if isinstance(v, str):
        return v[:1000]
    if depth <= 0:
        raise ProtocolError(f"{what}: nested too deeply")
    if isinstance(v, list):
        if len(v) > 500:
            raise ProtocolError(f"{what}: too many items")
        return [_scalar_tree(x, depth - 1, what) for x in v]
    if isinstance(v, dict):
        if len(v) > 200:
            raise ProtocolError(f"{what}: too many keys")
        return {str(k)[:100]: _scalar_tree(x, depth - 1, what) for k, x in v.items()}
    raise ProtocolError(f"{what}: unexpected value")


def _function_info(v):
    if not isinstance(v, dict):
        raise ProtocolError("functions: not an object")
    if len(v) > 100:
        raise ProtocolError("functions: too many entries")
    out = {}
    for name, e in v.items():
        if not isinstance(e, dict):
            raise ProtocolError("functions: an entry is not an object")
        entry = {}
        for k in ("defined", "callable"):
            if not isinstance(e.get(k), bool):
                raise ProtocolError(f"functions: {k} is not a boolean")
            entry[k] = e[k]
        for k in ("filename", "module", "signature"):
            x = e.get(k)
            if x is not None and not isinstance(x, str):
                raise ProtocolError(f"functions: {k} is not a string")
            entry[k] = None if x is None else x[:1000]
        out[str(name)[:100]] = entry
    return out


def control_message(data):
    """One message from the sandbox's control socket (untrusted), checked against its schema.

    ``{"ev": "stmt", "unit", "stmt", "line"}`` (non-negative ints) or
    ``{"ev": "ready", "notes", "functions", "isolation", "blocked"}``; the event of
    any other message is kept alone (its fields are dropped). Raises
    :class:`ProtocolError` on a message that breaks the schema.
    """
    msg = loads_untrusted(data, max_bytes=MAX_CONTROL, clean=True)
    if not isinstance(msg, dict):
        raise ProtocolError("control message is not an object")
    ev = msg.get("ev")
    if ev == "stmt":
        vals = {k: msg.get(k, 0 if k == "line" else None) for k in ("unit", "stmt", "line")}
        if not all(type(x) is int and 0 <= x < 2**31 for x in vals.values()):
            raise ProtocolError("stmt message: unit, stmt and line must be non-negative integers")
        return {"ev": "stmt", **vals}
    if ev == "ready":
        iso = msg.get("isolation")
        if iso is not None and not isinstance(iso, dict):
            raise ProtocolError("ready message: isolation is not an object")
        return {"ev": "ready",
                "notes": _texts(msg.get("notes"), 200, 300, "ready message: notes"),
                "functions": _function_info(msg.get("functions") or {}),
                "isolation": _scalar_tree(iso or {}, 4, "ready message: isolation"),
                "blocked": _texts(msg.get("blocked"), 100, 200, "ready message: blocked")}
    if not isinstance(ev, str):
        raise ProtocolError("control message without an event")
    return {"ev": ev[:40]}


def is_sparse(obj):
    """Whether ``obj`` is a SciPy sparse matrix or array (any subclass); SciPy is not imported if it is not loaded."""
    mod = _sys.modules.get("scipy.sparse")
    if mod is None:
        return False
    try:
        return bool(mod.issparse(obj))
    except BaseException:  # noqa: BLE001 - a hostile object
        return False
