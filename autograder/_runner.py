"""The child side of grading: load a submission and serve calls of its functions.

This file is run as a script (``python -I -S _runner.py JOB REQ_FD RES_FD``) in a
scratch directory by :mod:`autograder.sandbox`; it imports nothing from the
``autograder`` package (whose import is blocked here anyway), only the standard
library and NumPy. The grader's own process imports it as a module for the wire
format helpers (:func:`pack_frame`, :func:`encode_args`, :func:`decode_result`
...), which are shared by both sides.

Order of events in the child:

1. read the job (JSON) and import NumPy while still privileged;
2. isolate: new network and PID namespaces (``unshare``; with the PID namespace
   the runner forks and its child, process 1 of the namespace, carries on), an
   unprivileged uid/gid when running as root, ``no_new_privs``, a parent-death
   signal, resource limits (CPU, address space, file size, number of processes,
   core dumps);
3. install an audit hook that refuses imports of the blocked packages
   (``slamlib``, ``autograder``), reads of their files, new processes, sockets
   and ``ctypes`` symbol lookups, and records every refusal;
4. execute the submission's top-level statements one by one in a fresh module
   named ``submission`` (a failing statement is recorded and skipped);
5. answer call requests: each request names a function and its arguments; the
   reply carries the result as plain arrays (never pickles), the error if the
   call raised, which arguments the call modified and the refused operations.

Frames on both pipes are ``MAGIC, len(header), len(payload)`` followed by a
JSON header and raw array bytes.
"""

from __future__ import annotations

import json
import os
import re
import struct
import sys

# the runner's own references, taken before any submission code runs (a submission that
# monkeypatches json, os or numpy attributes does not change what the runner calls)
_dumps, _loads = json.dumps, json.loads
_write, _read = os.write, os.read

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
def _short(text, n=300):
    text = str(text)
    return text if len(text) <= n else text[: n - 3] + "..."


def _encode_item(obj, parts, size, np):
    info = {}
    try:
        info["py"] = _short(type(obj).__name__, 60)
        info["int_like"] = bool(isinstance(obj, (int, np.integer)) and not isinstance(obj, (bool, np.bool_)))
        info["subclass"] = (_short(type(obj).__name__, 60)
                            if isinstance(obj, np.ndarray) and type(obj) is not np.ndarray else None)
        a = np.asarray(obj)
        if type(a) is not np.ndarray:
            a = a.view(np.ndarray)
    except BaseException as exc:  # a hostile __array__ or __class__
        return {"t": "bad", "why": _short(f"numpy.asarray() failed on the result: {type(exc).__name__}: {exc}"), **info}
    if a.dtype.kind not in _DTYPE_KINDS or a.dtype.hasobject or a.dtype.names is not None:
        return {"t": "bad", "why": _short(f"numpy.asarray() of the result has dtype {a.dtype}"),
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
            return {"t": "item", "value": {"t": "bad", "why": _short(f"could not read the result: {exc}")}}, b""
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
        return Value(None, _short(why if isinstance(why, str) else "unreadable result"), py[:60], int_like, sub,
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


# =========================================================================== child process
def _send(fd, header, payload=b""):
    data = memoryview(pack_frame(header, payload))
    while data:
        n = _write(fd, data)
        data = data[n:]


def _recv(fd, buf):
    while True:
        got = parse_frame(buf)
        if got is not None:
            header, payload, used = got
            del buf[:used]
            return header, payload
        chunk = _read(fd, 1 << 20)
        if not chunk:
            return None
        buf.extend(chunk)


def _world_accessible(path):
    """Whether a user outside owner and group can read ``path`` and reach it."""
    import stat

    path = os.path.abspath(path)
    parts = path.split(os.sep)
    cur = os.sep
    for p in parts[1:]:
        try:
            st = os.stat(cur)
        except OSError:
            return False
        if not st.st_mode & stat.S_IXOTH:
            return False
        cur = os.path.join(cur, p)
    try:
        st = os.stat(path)
    except OSError:
        return True  # missing entries do not matter
    need = stat.S_IROTH | (stat.S_IXOTH if stat.S_ISDIR(st.st_mode) else 0)
    return st.st_mode & need == need


def _libc():
    import ctypes
    import ctypes.util

    return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)


def _namespaces(job, iso, libc, root):
    """New network and PID namespaces (and a user namespace when not root).

    With a new PID namespace the process forks: the child is process 1 of the
    namespace and goes on to run the submission; it cannot see or signal any
    process outside, and everything in the namespace dies with it. The parent
    (still outside) only waits and then ends the way the child ended, so the
    grader sees the child's exit status or signal.
    """
    import ctypes

    NEWNET, NEWUSER, NEWPID = 0x40000000, 0x10000000, 0x20000000
    net = NEWNET if job.get("netns", True) else 0
    user = 0 if root else NEWUSER
    tries = [net | NEWPID, net, NEWPID, 0] if net else [NEWPID, 0]
    got, err = 0, None
    for flags in tries:
        if libc.unshare(flags | (user if flags else 0)) == 0:
            got = flags
            break
        err = err or os.strerror(ctypes.get_errno())
    iso["netns"] = bool(got & NEWNET)
    iso["pidns"] = bool(got & NEWPID)
    iso["userns"] = bool(got) and not root
    if err and got != tries[0]:
        iso["netns_error" if not got & NEWNET else "pidns_error"] = err
    if got & NEWPID:
        pid = os.fork()
        if pid:
            _mirror_child(pid)


def _mirror_child(pid):
    """Outside the PID namespace: wait for its process 1, then end as it ended."""
    import signal

    for fd in range(3, 1024):  # keep only stdio: the pipes' other ends must see the child's EOF
        try:
            os.close(fd)
        except OSError:
            pass
    while True:
        try:
            _, status = os.waitpid(pid, 0)
            break
        except InterruptedError:
            continue
    if os.WIFSIGNALED(status):
        sig = os.WTERMSIG(status)
        try:
            import resource

            resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
            signal.signal(sig, signal.SIG_DFL)
            os.kill(os.getpid(), sig)
        except (OSError, ValueError):
            pass
        os._exit(128 + sig)
    os._exit(os.WEXITSTATUS(status) if os.WIFEXITED(status) else 1)


def _isolate(job, iso, np):
    """Network namespace, uid drop, prctl and rlimits; fills ``iso`` with what held."""
    import ctypes
    import resource

    libc = _libc()
    root = os.geteuid() == 0
    iso["root"] = root
    _namespaces(job, iso, libc, root)
    if root and job.get("uid") is not None:
        # keep the interpreter's own files reachable: directories only root can
        # traverse (a Python installed under /root) are reopened as fd paths
        remapped = []
        for i, p in enumerate(list(sys.path)):
            if p and os.path.isdir(p) and not _world_accessible(p):
                fd = os.open(p, os.O_RDONLY | os.O_DIRECTORY)
                new = f"/proc/self/fd/{fd}"
                sys.path[i] = new
                remapped.append((p, new))
        if remapped:
            for mod in list(sys.modules.values()):
                mp = getattr(mod, "__path__", None)
                if isinstance(mp, list):
                    for k, entry in enumerate(mp):
                        for old, new in remapped:
                            if isinstance(entry, str) and (entry == old or entry.startswith(old + os.sep)):
                                mp[k] = new + entry[len(old):]
            sys.path_importer_cache.clear()
        iso["remapped_paths"] = len(remapped)
        try:
            os.setgroups([])
            os.setgid(int(job["gid"]))
            os.setuid(int(job["uid"]))
            iso["uid"] = os.getuid()
        except OSError as exc:
            iso["uid_error"] = str(exc)
    else:
        iso["uid"] = os.getuid()
    iso["privileged"] = os.geteuid() == 0
    PR_SET_PDEATHSIG, PR_SET_NO_NEW_PRIVS = 1, 38
    iso["no_new_privs"] = libc.prctl(PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0) == 0
    libc.prctl(PR_SET_PDEATHSIG, 9, 0, 0, 0)
    lim = job.get("limits", {})
    applied = {}
    for name, value in (("RLIMIT_CPU", lim.get("cpu")), ("RLIMIT_AS", lim.get("as")), ("RLIMIT_FSIZE", lim.get("fsize")),
                        ("RLIMIT_NPROC", lim.get("nproc")), ("RLIMIT_CORE", 0), ("RLIMIT_NOFILE", lim.get("nofile"))):
        if value is None:
            continue
        try:
            resource.setrlimit(getattr(resource, name), (int(value), int(value)))
            applied[name] = int(value)
        except (ValueError, OSError) as exc:
            applied[name] = f"failed: {exc}"
    iso["rlimits"] = applied
    return libc


_BLOCKED_EVENTS = ("os.fork", "os.forkpty", "os.exec", "os.posix_spawn", "os.spawn", "os.system", "subprocess.Popen",
                   "os.kill", "os.killpg", "socket.connect", "socket.bind", "socket.sendto", "socket.sendmsg",
                   "ctypes.dlopen", "ctypes.dlsym", "ctypes.dlsym/handle", "pty.spawn")


def _install_audit_hook(blocked_modules, blocked_paths, attempts, processes=True):
    """Refuse (and record) imports of blocked packages, reads of their files, and new processes."""
    roots = tuple(blocked_modules)
    prefixes = tuple(os.path.realpath(p) + os.sep for p in blocked_paths)
    events = set(_BLOCKED_EVENTS) if processes else set()
    busy = [False]

    def record(what):
        if len(attempts) < 100:
            attempts.append(what)

    def hook(event, args):
        if busy[0]:
            return
        if event == "import":
            name = args[0] if args else ""
            if isinstance(name, str) and name.partition(".")[0] in roots:
                record(f"import {name}")
                raise ImportError(f"{name} is not available while grading: graded functions must be your own code")
        elif event == "open" and prefixes:
            path = args[0] if args else None
            if isinstance(path, bytes):
                path = path.decode("utf-8", "replace")
            if isinstance(path, str):
                busy[0] = True
                try:
                    full = os.path.realpath(path)
                finally:
                    busy[0] = False
                if any((full + os.sep).startswith(p) for p in prefixes):
                    record(f"open {path}")
                    raise PermissionError(f"reading {path} is not allowed while grading")
        elif event in events:
            record(event)
            raise PermissionError(f"{event} is not allowed while grading")

    sys.addaudithook(hook)

    class _BlockedFinder:
        """First on sys.meta_path: importlib.import_module raises no audit event, so refuse here too."""

        @staticmethod
        def find_spec(name, path=None, target=None):
            if name.partition(".")[0] in roots:
                record(f"import {name}")
                raise ImportError(f"{name} is not available while grading: graded functions must be your own code")
            return None

    sys.meta_path.insert(0, _BlockedFinder)
    for name in list(sys.modules):
        if name.partition(".")[0] in roots:
            del sys.modules[name]


def _load_submission(job, attempts):
    """Execute the submission statement by statement in a fresh module."""
    import ast
    import linecache
    import types

    mod = types.ModuleType("submission")
    mod.__file__ = job.get("display_name", "submission.py")
    sys.modules["submission"] = mod
    notes = []
    for unit in job.get("units", []):
        src, filename, label = unit["source"], unit["filename"], unit.get("label", unit["filename"])
        linecache.cache[filename] = (len(src), None, src.splitlines(True), filename)
        try:
            tree = ast.parse(src, filename=filename)
        except SyntaxError as exc:
            notes.append(f"{label}: syntax error at line {exc.lineno}: {exc.msg} (skipped)")
            continue
        for stmt in tree.body:
            before = len(attempts)
            try:
                code = compile(ast.Module(body=[stmt], type_ignores=[]), filename, "exec")
                exec(code, mod.__dict__)
            except BaseException as exc:  # noqa: BLE001 - SystemExit, KeyboardInterrupt too
                tb = _frames(exc.__traceback__)
                line = next((fr.lineno for fr in reversed(tb) if fr.filename == filename), stmt.lineno)
                what = "called sys.exit()" if isinstance(exc, SystemExit) else f"{type(exc).__name__}: {_short(exc, 200)}"
                notes.append(f"{label}, line {line}: {what} (statement skipped)")
            if len(attempts) > before:
                notes.append(f"{label}: refused while loading: {', '.join(attempts[before:])}")
    return mod, notes


def _frames(tb):
    """Stack frames of a traceback without reading any source file."""
    import traceback

    return traceback.StackSummary.extract(traceback.walk_tb(tb), lookup_lines=False)


def _format_exc(exc, prefixes):
    import linecache

    frames = _frames(exc.__traceback__)
    keep = [f for f in frames if any(f.filename.startswith(p) for p in prefixes)] or frames[-1:]
    lines = []
    for f in keep[-4:]:
        src = linecache.cache.get(f.filename)
        text = src[2][f.lineno - 1].strip() if (src and f.lineno and 0 < f.lineno <= len(src[2])) else ""
        lines.append(f"  {f.filename}, line {f.lineno}, in {f.name}" + (f"\n    {text}" if text else ""))
    msg = f"{type(exc).__name__}: {_short(exc, 500)}"
    return msg, "\n".join(lines)


def _same(a, b, np):
    if isinstance(a, np.ndarray):
        return (isinstance(b, np.ndarray) and a.shape == b.shape and a.dtype == b.dtype
                and a.tobytes() == b.tobytes())
    return True


def _serve(job, req_fd, res_fd, mod, attempts, np):
    import random
    import time

    names = job.get("functions", [])
    prefixes = tuple(u["filename"] for u in job.get("units", []))
    buf = bytearray()
    while True:
        got = _recv(req_fd, buf)
        if got is None:
            return
        header, payload = got
        op = header.get("op")
        if op == "exit":
            return
        if op != "call":
            _send(res_fd, {"status": "protocol", "error": f"unknown op {op!r}"})
            continue
        name = header.get("fn")
        if name not in names:
            _send(res_fd, {"status": "protocol", "error": f"function {name!r} not served here"})
            continue
        fn = mod.__dict__.get(name)
        try:
            args, kwargs = decode_args(header, payload, np)
        except (ProtocolError, KeyError, TypeError, ValueError) as exc:
            _send(res_fd, {"status": "protocol", "error": str(exc)})
            continue
        pristine = [np.array(a, copy=True) if isinstance(a, np.ndarray) else None for a in args]
        pristine_kw = {k: (np.array(v, copy=True) if isinstance(v, np.ndarray) else None) for k, v in kwargs.items()}
        gs = header.get("global_seed")
        if isinstance(gs, int):
            np.random.seed(gs % (2**32))
            random.seed(gs)
        before = len(attempts)
        t0 = time.perf_counter()
        status, result_desc, rpayload, err, where = "ok", None, b"", None, None
        try:
            if not callable(fn):
                raise TypeError(f"{name} is not a function")
            out = fn(*args, **kwargs)
        except BaseException as exc:  # noqa: BLE001 - report everything, SystemExit included
            status = "error"
            err, where = _format_exc(exc, prefixes)
            if isinstance(exc, SystemExit):
                err = f"SystemExit: the function called sys.exit({_short(exc.code, 50)})"
        elapsed = time.perf_counter() - t0
        if status == "ok":
            try:
                result_desc, rpayload = encode_result(out, np)
            except BaseException as exc:  # noqa: BLE001
                status, err = "error", f"the result could not be read: {type(exc).__name__}: {_short(exc)}"
        mutated = []
        params = header.get("names") or []
        for i, (a, p) in enumerate(zip(args, pristine)):
            if p is not None and not _same(a, p, np):
                mutated.append(params[i] if i < len(params) else f"argument {i + 1}")
        for k, p in pristine_kw.items():
            if p is not None and not _same(kwargs[k], p, np):
                mutated.append(k)
        _send(res_fd, {"status": status, "result": result_desc, "error": err, "where": where, "mutated": mutated,
                       "blocked": attempts[before:], "elapsed": elapsed}, rpayload)


def frozen_numpy(np):
    """The NumPy entry points the runner uses, captured before submission code runs."""
    import types

    return types.SimpleNamespace(
        asarray=np.asarray, array=np.array, ndarray=np.ndarray, integer=np.integer, bool_=np.bool_,
        frombuffer=np.frombuffer, dtype=np.dtype,
        random=types.SimpleNamespace(default_rng=np.random.default_rng, seed=np.random.seed))


def main(argv):
    job_path, req_fd, res_fd = argv[1], int(argv[2]), int(argv[3])
    with open(job_path, encoding="utf-8") as fh:
        job = json.load(fh)
    for p in job.get("sys_path", []):
        if p not in sys.path:
            sys.path.append(p)
    try:
        sys.stdout.reconfigure(line_buffering=True)
        sys.stderr.reconfigure(line_buffering=True)
    except (AttributeError, ValueError):
        pass
    import numpy as np
    import numpy.linalg  # noqa: F401
    import numpy.random  # noqa: F401
    # what the runner itself needs later, loaded while every file is readable
    import ast, ctypes, ctypes.util, inspect, linecache, random, resource, stat, time, traceback, types  # noqa: E401,F401

    npx = frozen_numpy(np)
    iso = {}
    if job.get("isolate", True):
        _isolate(job, iso, np)
    attempts = []
    if job.get("audit", True):
        _install_audit_hook(job.get("blocked_modules", []), job.get("blocked_paths", []), attempts,
                            processes=job.get("block_processes", True))
    iso["audit_hook"] = bool(job.get("audit", True))
    mod, notes = _load_submission(job, attempts)
    info = {}
    for name in job.get("functions", []):
        fn = mod.__dict__.get(name)
        entry = {"defined": fn is not None, "callable": callable(fn)}
        code = getattr(fn, "__code__", None)
        if code is not None:
            entry["filename"] = str(getattr(code, "co_filename", ""))
        entry["module"] = _short(getattr(fn, "__module__", None), 100) if fn is not None else None
        try:
            import inspect

            entry["signature"] = str(inspect.signature(fn)) if callable(fn) else None
        except (TypeError, ValueError):
            entry["signature"] = None
        info[name] = entry
    _send(res_fd, {"status": "ready", "notes": notes, "functions": info, "isolation": iso,
                   "blocked": list(attempts)})
    _serve(job, req_fd, res_fd, mod, attempts, npx)


if __name__ == "__main__":
    try:
        main(sys.argv)
    finally:
        sys.stdout.flush()
    os._exit(0)
