"""The child side of grading: load a submission once, then fork a fresh worker per function.

This file is run as a script (``python -I -S _runner.py CTL_FD``) by
:mod:`autograder.sandbox`; it imports the standard library, NumPy and the wire
format (``wire.py`` beside it, which both sides share, loaded by its path before
the child isolates itself) and nothing else of the ``autograder`` package.

Order of events in the child:

1. read the job (one frame on stdin) and import NumPy while still privileged;
2. isolate, before any line of the submission runs: new mount, PID, network, IPC
   and UTS namespaces (``unshare``; inside a user namespace when the grader is not
   root); with the PID namespace the runner forks and its child, process 1 of the
   namespace, carries on. That process builds a minimal root (a tmpfs with
   read-only binds of the system libraries, the Python standard library and the
   NumPy and SciPy packages only, a private size-capped ``/tmp`` and ``/dev/shm``, a
   fresh ``/proc``, ``/dev/null``, ``zero``, ``urandom``), moves into it with ``pivot_root`` and
   detaches the old root: ``slamlib``, the tests, the bundle, the batch folder and
   other submissions do not exist there. Then an unprivileged uid/gid (root) or no
   capabilities (user namespace), ``no_new_privs``, a parent-death signal,
   resource limits;
3. install an audit hook (a second line: imports of ``slamlib``/``autograder``,
   reads of their files, new processes, sockets, ``ctypes`` lookups);
4. execute the submission's top-level statements one by one in a fresh module
   named ``submission``, announcing each on the control socket so the grader can
   skip one that hangs;
5. become the zygote: for each ``fork`` request (three pipe ends passed as
   descriptors) fork a worker that answers call requests on those pipes; kill a
   worker on request; reap everything.

Frames on the pipes are ``MAGIC, len(header), len(payload)`` followed by a JSON
header and raw array bytes; control messages are JSON datagrams.
"""

from __future__ import annotations

import json
import os
import sys

# the runner's own references, taken before any submission code runs (a submission that
# monkeypatches json, os or numpy attributes does not change what the runner calls)
_dumps, _loads = json.dumps, json.loads
_write, _read = os.write, os.read


def _load_wire():
    """``wire.py`` from this script's folder: ``python -I`` keeps that folder off ``sys.path``, and importing
    the ``autograder`` package here would run its ``__init__``; the file is read now, before isolation."""
    import importlib.util

    path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "wire.py")
    spec = importlib.util.spec_from_file_location("_autograder_wire", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


if __package__:  # imported as autograder._runner (by the tests)
    from . import wire
else:  # the child's script
    wire = _load_wire()
ProtocolError, pack_frame, parse_frame = wire.ProtocolError, wire.pack_frame, wire.parse_frame
decode_args, encode_result, _short = wire.decode_args, wire.encode_result, wire.shorten
# =========================================================================== child process
def _send(fd, header, payload=b""):
    data = memoryview(pack_frame(header, payload))
    while data:
        n = _write(fd, data)
        data = data[n:]


def _recv(fd, buf):
    while True:
        got = parse_frame(buf, max_header=wire.MAX_JOB)  # the grader's frames (the job holds the sources)
        if got is not None:
            header, payload, used = got
            del buf[:used]
            return header, payload
        chunk = _read(fd, 1 << 20)
        if not chunk:
            return None
        buf.extend(chunk)


def _ctl_send(sock, msg):
    """One message to the grader on the control socket (SOCK_SEQPACKET keeps message boundaries)."""
    try:
        sock.send(_dumps(msg, allow_nan=True, separators=(",", ":")).encode("utf-8"))
    except OSError:
        pass


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

    lib = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
    lib.mount.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_char_p, ctypes.c_ulong, ctypes.c_char_p]
    lib.umount2.argtypes = [ctypes.c_char_p, ctypes.c_int]
    return lib


def _check(libc, ret, what):
    import ctypes

    if ret != 0:
        e = ctypes.get_errno()
        raise OSError(e, f"{what}: {os.strerror(e)}")


NEWNS, NEWUTS, NEWIPC, NEWUSER, NEWPID, NEWNET = 0x20000, 0x04000000, 0x08000000, 0x10000000, 0x20000000, 0x40000000
MS_RDONLY, MS_NOSUID, MS_NODEV, MS_NOEXEC, MS_REMOUNT, MS_BIND, MS_REC, MS_PRIVATE = 1, 2, 4, 8, 32, 4096, 16384, 1 << 18
MS_NOATIME, MS_NODIRATIME, MS_RELATIME = 1024, 2048, 1 << 21
# pivot_root's system call number: x86_64 155, aarch64 (and other asm-generic ABIs) 41
SYS_PIVOT_ROOT = 155 if os.uname().machine in ("x86_64", "amd64") else 41
MNT_DETACH = 2


def _namespaces(job, iso, libc, root):
    """New mount, PID, network, IPC and UTS namespaces (inside a user namespace when not root).

    With a new PID namespace the process forks: the child is process 1 of the
    namespace and goes on to build the sandbox and run the submission; it cannot
    see or signal any process outside, and everything in the namespace dies with
    it. The parent (still outside) only waits and then ends the way the child
    ended, so the grader sees the child's exit status or signal.
    """
    import ctypes

    net = NEWNET if job.get("netns", True) else 0
    mnt = NEWNS if job.get("fs") else 0
    user = 0 if root else NEWUSER
    base = NEWIPC | NEWUTS
    tries = [mnt | NEWPID | net | base, NEWPID | net | base, NEWPID | net, net, NEWPID, 0]
    got, err = 0, None
    uid, gid = os.getuid(), os.getgid()
    for flags in dict.fromkeys(tries):
        if flags == 0:
            break
        if libc.unshare(flags | user) == 0:
            got = flags
            break
        err = err or os.strerror(ctypes.get_errno())
    iso["userns"] = bool(got) and not root
    if iso["userns"]:
        try:  # map the grader's uid/gid to root of the new user namespace (capabilities are dropped later)
            for name, text in (("setgroups", "deny"), ("uid_map", f"0 {uid} 1"), ("gid_map", f"0 {gid} 1")):
                with open(f"/proc/self/{name}", "w") as fh:
                    fh.write(text)
        except OSError as exc:
            iso["userns_map_error"] = str(exc)
    iso["mountns"] = bool(got & NEWNS)
    iso["netns"] = bool(got & NEWNET)
    iso["pidns"] = bool(got & NEWPID)
    if err and got != tries[0]:
        iso["namespace_error"] = err
        if not got & NEWNET:
            iso["netns_error"] = err
        if not got & NEWPID:
            iso["pidns_error"] = err
        if not got & NEWNS:
            iso["mountns_error"] = err
    if got & NEWPID:
        pid = os.fork()
        if pid:
            _mirror_child(pid)
    return got


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


def _under(path, roots):
    return any(path == r or path.startswith(r.rstrip("/") + "/") for r in roots)


def _build_root(fs, iso, libc):
    """A minimal root: tmpfs, read-only binds of the system libraries, Python and NumPy/SciPy only.

    Builds it on a tmpfs mounted over ``/tmp`` (in this private mount namespace the
    host's ``/tmp`` is not touched), then ``pivot_root`` into it and detaches the old
    root. Sources are pinned with ``O_PATH`` descriptors first, so a source under
    the host's ``/tmp`` is still reachable. Site-packages folders inside a bound tree
    are covered by empty tmpfs, so only the allowed packages (NumPy, SciPy and their
    ``.libs``) show through; ``slamlib``, ``autograder``, the bundle, the batch folder,
    other submissions and the grader's scratch space do not exist in this root.
    """
    R = "/tmp"
    ro_fl = MS_NOSUID | MS_NODEV

    def pin(p):
        try:
            return os.open(p, os.O_PATH | os.O_CLOEXEC)
        except OSError:
            return None

    system = [p for p in fs.get("system", []) if os.path.lexists(p)]
    links = {p: os.readlink(p) for p in system if os.path.islink(p)}
    binds = [p for p in system if p not in links] + [p for p in fs.get("python", []) if os.path.exists(p)]
    allow = [p for p in fs.get("allow", []) if os.path.exists(p)]
    pins = {p: pin(p) for p in binds + allow}
    _check(libc, libc.mount(None, b"/", None, MS_REC | MS_PRIVATE, None), "make mounts private")
    _check(libc, libc.mount(b"tmpfs", R.encode(), b"tmpfs", ro_fl, f"size={fs.get('root_size', '8m')},mode=0755".encode()),
           "root tmpfs")

    def mkpoint(dst, isdir):
        if isdir:
            os.makedirs(dst, mode=0o755, exist_ok=True)
        else:
            os.makedirs(os.path.dirname(dst), mode=0o755, exist_ok=True)
            if not os.path.exists(dst):
                os.close(os.open(dst, os.O_CREAT | os.O_WRONLY, 0o644))

    def bind(src, fd, ro=True):
        dst = R + src
        mkpoint(dst, os.path.isdir(f"/proc/self/fd/{fd}"))
        _check(libc, libc.mount(f"/proc/self/fd/{fd}".encode(), dst.encode(), None, MS_BIND | MS_REC, None), f"bind {src}")
        if ro:
            st = os.statvfs(dst)
            keep = st.f_flag & (MS_NOSUID | MS_NODEV | MS_NOEXEC | MS_NOATIME | MS_NODIRATIME)
            if st.f_flag & 4096:  # ST_RELATIME
                keep |= MS_RELATIME
            _check(libc, libc.mount(None, dst.encode(), None, MS_BIND | MS_REMOUNT | MS_RDONLY | keep, None),
                   f"read-only {src}")

    bound = []
    for p, target in links.items():
        os.symlink(target, R + p)
    for p in binds:
        if _under(p, bound) or pins.get(p) is None:
            continue
        bind(p, pins[p])
        bound.append(p)
    hidden = []
    for h in fs.get("hide", []):
        if _under(h, bound) and os.path.isdir(R + h) and not _under(h, hidden):
            _check(libc, libc.mount(b"tmpfs", (R + h).encode(), b"tmpfs", ro_fl, b"size=64k,mode=0755"), f"hide {h}")
            hidden.append(h)
    for a in allow:
        if _under(a, bound) and not _under(a, hidden):
            continue  # already visible
        if pins.get(a) is not None:
            bind(a, pins[a])
    for h in hidden:
        libc.mount(None, (R + h).encode(), None, MS_REMOUNT | MS_RDONLY | ro_fl, None)
    for fd in pins.values():
        if fd is not None:
            os.close(fd)
    for d in ("tmp", "dev", "proc", "etc"):
        os.makedirs(f"{R}/{d}", mode=0o755, exist_ok=True)
    _check(libc, libc.mount(b"tmpfs", f"{R}/tmp".encode(), b"tmpfs", ro_fl,
                            f"size={fs.get('tmp_size', '64m')},mode=1777".encode()), "private /tmp")
    _check(libc, libc.mount(b"tmpfs", f"{R}/dev".encode(), b"tmpfs", MS_NOSUID, b"size=64k,mode=0755"), "/dev")
    for name in ("null", "zero", "full", "random", "urandom"):
        if os.path.exists(f"/dev/{name}"):
            mkpoint(f"{R}/dev/{name}", False)
            _check(libc, libc.mount(f"/dev/{name}".encode(), f"{R}/dev/{name}".encode(), None, MS_BIND, None),
                   f"/dev/{name}")
    os.makedirs(f"{R}/dev/shm", mode=0o755)
    _check(libc, libc.mount(b"tmpfs", f"{R}/dev/shm".encode(), b"tmpfs", ro_fl,
                            f"size={fs.get('shm_size', '16m')},mode=1777".encode()), "private /dev/shm")
    for name, target in (("fd", "/proc/self/fd"), ("stdin", "/proc/self/fd/0"), ("stdout", "/proc/self/fd/1"),
                         ("stderr", "/proc/self/fd/2")):
        os.symlink(target, f"{R}/dev/{name}")
    libc.mount(None, f"{R}/dev".encode(), None, MS_REMOUNT | MS_RDONLY | MS_NOSUID, None)
    _check(libc, libc.mount(b"proc", f"{R}/proc".encode(), b"proc", MS_NOSUID | MS_NODEV | MS_NOEXEC, None), "/proc")
    with open(f"{R}/etc/passwd", "w") as fh:
        fh.write("root:x:0:0:root:/tmp:/bin/false\nstudent:x:65534:65534:student:/tmp:/bin/false\n")
    with open(f"{R}/etc/group", "w") as fh:
        fh.write("root:x:0:\nstudent:x:65534:\n")
    os.makedirs(f"{R}/.old")
    _check(libc, libc.syscall(SYS_PIVOT_ROOT, R.encode(), f"{R}/.old".encode()), "pivot_root")
    os.chdir("/")
    _check(libc, libc.umount2(b"/.old", MNT_DETACH), "detach the old root")
    os.rmdir("/.old")
    libc.mount(None, b"/", None, MS_REMOUNT | MS_RDONLY | ro_fl, None)
    os.chdir("/tmp")
    iso["fs_root"] = {"bound": bound, "hidden": hidden, "links": sorted(links)}


def _drop_capabilities(libc):
    """All capabilities off (user-namespace root keeps none): capset with empty sets."""
    import ctypes

    hdr = (ctypes.c_uint32 * 2)(0x20080522, 0)  # _LINUX_CAPABILITY_VERSION_3, this process
    data = (ctypes.c_uint32 * 6)()
    return libc.capset(ctypes.byref(hdr), ctypes.byref(data)) == 0


def _isolate(job, iso, np):
    """Namespaces, the minimal root, the uid drop, prctl and rlimits; fills ``iso`` with what held."""
    import resource

    libc = _libc()
    root = os.geteuid() == 0
    iso["root"] = root
    got = _namespaces(job, iso, libc, root)
    if got & NEWNS:
        try:
            _build_root(job["fs"], iso, libc)
            iso["fs"] = True
        except OSError as exc:
            iso["fs"] = False
            iso["fs_error"] = str(exc)
    else:
        iso["fs"] = False
    if root and job.get("uid") is not None:
        if not iso.get("fs"):
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
        if iso.get("userns"):
            iso["caps_dropped"] = _drop_capabilities(libc)
    iso["privileged"] = os.geteuid() == 0 and not iso.get("userns")
    PR_SET_PDEATHSIG, PR_SET_DUMPABLE, PR_SET_NO_NEW_PRIVS = 1, 4, 38
    iso["no_new_privs"] = libc.prctl(PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0) == 0
    libc.prctl(PR_SET_PDEATHSIG, 9, 0, 0, 0)  # credentials changed: set again
    libc.prctl(PR_SET_DUMPABLE, 0, 0, 0, 0)  # no ptrace between the zygote and its workers
    # what a student can still read of the reference and the tests, as this process sees it
    iso["reference_readable"] = sorted(p for p in job.get("blocked_paths", []) if os.path.exists(p)
                                       and os.access(p, os.R_OK))
    lim = job.get("limits", {})
    applied = {}
    unique_uid = root and "uid_error" not in iso and job.get("uid") is not None
    for name, value in (("RLIMIT_CPU", lim.get("cpu")), ("RLIMIT_AS", lim.get("as")), ("RLIMIT_FSIZE", lim.get("fsize")),
                        ("RLIMIT_CORE", 0), ("RLIMIT_NOFILE", lim.get("nofile"))):
        if value is None:
            continue
        try:
            resource.setrlimit(getattr(resource, name), (int(value), int(value)))
            applied[name] = int(value)
        except (ValueError, OSError) as exc:
            applied[name] = f"failed: {exc}"
    if unique_uid:
        # the zygote may fork its workers (counted on this uid alone); loading may not
        try:
            resource.setrlimit(resource.RLIMIT_NPROC, (1, 1 + int(job.get("max_workers", 8))))
        except (ValueError, OSError):
            pass
    applied["RLIMIT_NPROC"] = int(lim.get("nproc", 0))  # applied in every worker before its first call
    iso["rlimits"] = applied
    return libc


_BLOCKED_EVENTS = ("os.fork", "os.forkpty", "os.exec", "os.posix_spawn", "os.spawn", "os.system", "subprocess.Popen",
                   "os.kill", "os.killpg", "socket.connect", "socket.bind", "socket.sendto", "socket.sendmsg",
                   "ctypes.dlopen", "ctypes.dlsym", "ctypes.dlsym/handle", "pty.spawn")


def _install_audit_hook(blocked_modules, blocked_paths, attempts, processes=True):
    """Refuse (and record) imports of blocked packages, reads of their files, and new processes.

    A second line only: anything in the submission's address space can undo it. The
    first line is the sandbox root, in which those files do not exist.
    """
    roots = tuple(blocked_modules)
    prefixes = tuple(os.path.realpath(p) + os.sep for p in blocked_paths)
    events = set(_BLOCKED_EVENTS) if processes else set()
    busy = [False]
    allowed = [True]  # the zygote's own fork of a worker passes

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
    return busy


def _load_submission(job, attempts, ctl):
    """Execute the submission statement by statement in a fresh module.

    Before each top-level statement the loader tells the grader which one it
    starts, so the grader can enforce a deadline per statement: a statement that
    hangs (an endless loop in a notebook cell) is skipped on the next load, as an
    interrupted cell would be, and the functions defined before and after it stay.
    """
    import ast
    import linecache
    import types

    mod = types.ModuleType("submission")
    mod.__file__ = job.get("display_name", "submission.py")
    sys.modules["submission"] = mod
    notes = []
    skip = {(int(u), int(s)) for u, s in job.get("skip", [])}
    for k, unit in enumerate(job.get("units", [])):
        src, filename, label = unit["source"], unit["filename"], unit.get("label", unit["filename"])
        linecache.cache[filename] = (len(src), None, src.splitlines(True), filename)
        try:
            tree = ast.parse(src, filename=filename)
        except (SyntaxError, ValueError) as exc:
            notes.append(f"{label}: syntax error at line {getattr(exc, 'lineno', '?')}: "
                         f"{getattr(exc, 'msg', exc)} (skipped)")
            continue
        for i, stmt in enumerate(tree.body):
            if (k, i) in skip:
                continue
            _ctl_send(ctl, {"ev": "stmt", "unit": k, "stmt": i, "line": stmt.lineno})
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
    """The exception and the frames of the submission's own code (never fails)."""
    import linecache

    try:
        frames = list(_frames(exc.__traceback__))
    except BaseException:  # noqa: BLE001 - a hostile traceback
        frames = []
    keep = [f for f in frames if any(str(f.filename) == p for p in prefixes)]
    if not keep:
        # raised before any of the submission's lines ran (a wrong signature: the call itself failed)
        keep = []
    lines = []
    for f in keep[-4:]:
        try:
            src = linecache.cache.get(f.filename)
            lineno = f.lineno or 0
            text = src[2][lineno - 1].strip() if (src and 0 < lineno <= len(src[2])) else ""
        except BaseException:  # noqa: BLE001
            text = ""
        lines.append(f"  {f.filename}, line {f.lineno}, in {f.name}" + (f"\n    {text}" if text else ""))
    try:
        msg = f"{type(exc).__name__}: {_short(exc, 500)}"
    except BaseException:  # noqa: BLE001 - a hostile __str__
        msg = type(exc).__name__
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


def _worker(job, ctl, fds, mod, attempts, npx, hook_busy):
    """A fresh process forked from the loaded submission: serves calls on its own pipes."""
    import resource

    req_fd, res_fd, out_fd = fds
    try:
        ctl.close()
    except OSError:
        pass
    os.dup2(out_fd, 1)
    os.dup2(out_fd, 2)
    os.close(out_fd)
    libc = _LIBC[0]
    if libc is not None:
        libc.prctl(1, 9, 0, 0, 0)  # PR_SET_PDEATHSIG: dies with the zygote
    nproc = int(job.get("limits", {}).get("nproc", 0))
    try:
        resource.setrlimit(resource.RLIMIT_NPROC, (nproc, nproc))
    except (ValueError, OSError):
        pass
    _run_then_exit(_serve, job, req_fd, res_fd, mod, attempts, npx)


def _run_then_exit(fn, *args):
    """Run ``fn(*args)``, flush stdout whatever happened, and end the process without cleanup."""
    try:
        fn(*args)
    finally:
        try:
            sys.stdout.flush()
        except BaseException:  # noqa: BLE001
            pass
        os._exit(0)


_LIBC = [None]


def _zygote(job, ctl, mod, attempts, npx, hook_busy):
    """Process 1 of the sandbox after loading: forks one worker per request, kills workers on request.

    Requests arrive on the control socket: ``fork`` (with the worker's three pipe
    ends passed as descriptors), ``kill`` and ``exit``. A worker is reaped as soon
    as it ends; so are orphans (this is the PID namespace's init).
    """
    import array
    import resource
    import select
    import signal
    import socket

    workers = {}  # id -> (pid, pidfd, the result pipe's write end: the exit status goes there)
    unique_uid = job.get("uid") is not None and os.getuid() == int(job["uid"])

    def reap():
        while True:
            try:
                pid, _ = os.waitpid(-1, os.WNOHANG)
            except ChildProcessError:
                return
            if pid == 0:
                return

    def kill(wid):
        entry = workers.pop(wid, None)
        if entry is None:
            return
        pid, pidfd, res_w = entry
        try:
            signal.pidfd_send_signal(pidfd, signal.SIGKILL)
        except OSError:
            pass
        try:
            os.waitpid(pid, 0)
        except ChildProcessError:
            pass
        os.close(pidfd)
        os.close(res_w)

    def ended(wid):
        """A worker ended by itself: tell the grader how, on the worker's own result pipe."""
        pid, pidfd, res_w = workers.pop(wid)
        code = None
        try:
            _, status = os.waitpid(pid, 0)
            code = os.waitstatus_to_exitcode(status)
        except (ChildProcessError, ValueError):
            pass
        if code is None:
            text = "the process ended"
        elif code < 0:
            try:
                text = f"killed by signal {signal.Signals(-code).name}"
            except ValueError:
                text = f"killed by signal {-code}"
        else:
            text = f"exit status {code}"
        try:
            os.set_blocking(res_w, False)
            _write(res_w, pack_frame({"status": "exited", "exit": text}))
        except OSError:
            pass
        os.close(pidfd)
        os.close(res_w)

    while True:
        watch = [ctl.fileno()] + [pfd for _, pfd, _ in workers.values()]
        try:
            ready, _, _ = select.select(watch, [], [], 5.0)
        except InterruptedError:
            continue
        for wid, (pid, pidfd, _) in list(workers.items()):
            if pidfd in ready:
                ended(wid)
        reap()
        if ctl.fileno() not in ready:
            continue
        try:
            data, anc, _, _ = ctl.recvmsg(1 << 16, socket.CMSG_SPACE(3 * 4))
        except InterruptedError:
            continue
        except OSError:
            data, anc = b"", []
        fds = []
        for level, kind, cdata in anc:
            if level == socket.SOL_SOCKET and kind == socket.SCM_RIGHTS:
                a = array.array("i")
                a.frombytes(cdata[: len(cdata) - (len(cdata) % a.itemsize)])
                fds.extend(a)
        if not data:
            for wid in list(workers):
                kill(wid)
            return
        try:
            msg = _loads(data.decode("utf-8"))
        except ValueError:
            msg = {}
        op = msg.get("op")
        if op == "fork" and len(fds) == 3:
            wid = msg.get("id")
            if unique_uid:
                try:
                    soft, hard = resource.getrlimit(resource.RLIMIT_NPROC)
                    resource.setrlimit(resource.RLIMIT_NPROC, (hard, hard))
                except (ValueError, OSError):
                    pass
            try:
                hook_busy[0] = True
                try:
                    pid = os.fork()
                finally:
                    hook_busy[0] = False
            except OSError:
                pid = -1
            if pid == 0:
                hook_busy[0] = False
                for _, pfd, rfd in workers.values():
                    for f in (pfd, rfd):
                        try:
                            os.close(f)
                        except OSError:
                            pass
                _worker(job, ctl, fds, mod, attempts, npx, hook_busy)
            keep = None
            if pid > 0:
                try:
                    workers[wid] = (pid, os.pidfd_open(pid), fds[1])
                    keep = fds[1]
                except OSError:
                    pass
            for fd in fds:
                if fd != keep:
                    os.close(fd)
        elif op == "kill":
            kill(msg.get("id"))
        elif op == "exit":
            for wid in list(workers):
                kill(wid)
            return
        else:
            for fd in fds:
                os.close(fd)


def main(argv):
    import socket

    ctl_fd = int(argv[1])
    _libc_early = _libc()
    _libc_early.prctl(1, 9, 0, 0, 0)  # PR_SET_PDEATHSIG: die with the grader
    buf = bytearray()
    got = _recv(0, buf)
    if got is None:
        os._exit(3)
    job = got[0]
    null = os.open("/dev/null", os.O_RDONLY)
    os.dup2(null, 0)
    os.close(null)
    ctl = socket.socket(fileno=ctl_fd)
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
    import array, ast, ctypes, ctypes.util, inspect, linecache, random, resource, select, signal, stat, time, traceback, types  # noqa: E401,F401,E501

    npx = frozen_numpy(np)
    iso = {}
    if job.get("isolate", True):
        _LIBC[0] = _isolate(job, iso, np)
    else:
        _LIBC[0] = _libc_early
    attempts = []
    hook_busy = [False]
    if job.get("audit", True):
        hook_busy = _install_audit_hook(job.get("blocked_modules", []), job.get("blocked_paths", []), attempts,
                                        processes=job.get("block_processes", True))
    iso["audit_hook"] = bool(job.get("audit", True))
    mod, notes = _load_submission(job, attempts, ctl)
    info = {}
    for name in job.get("functions", []):
        fn = mod.__dict__.get(name)
        entry = {"defined": fn is not None, "callable": callable(fn)}
        code = getattr(fn, "__code__", None)
        if code is not None:
            entry["filename"] = str(getattr(code, "co_filename", ""))
        entry["module"] = _short(getattr(fn, "__module__", None), 100) if fn is not None else None
        try:
            entry["signature"] = str(inspect.signature(fn)) if callable(fn) else None
        except (TypeError, ValueError):
            entry["signature"] = None
        info[name] = entry
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except BaseException:  # noqa: BLE001
        pass
    _ctl_send(ctl, {"ev": "ready", "notes": notes[:200], "functions": info, "isolation": iso,
                    "blocked": list(attempts)[:100]})
    _zygote(job, ctl, mod, attempts, npx, hook_busy)


if __name__ == "__main__":
    _run_then_exit(main, sys.argv)
