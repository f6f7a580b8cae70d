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
   other submissions do not exist there. Process 1 then forks the zygote and stays
   behind as a minimal init (no submission code, no signal handlers, no
   capabilities; it ends the namespace when the zygote, the grader or the control
   socket goes away). The zygote takes an unprivileged uid/gid (root) or drops its
   capabilities (user namespace), sets ``no_new_privs``, a parent-death signal and
   resource limits, joins a fresh session keyring and installs the seccomp filter;
3. install an audit hook (a second line: imports of ``slamlib``/``autograder``,
   reads of their files, new processes, sockets, ``ctypes`` lookups);
4. in a throwaway child (the probe), execute the submission's top-level statements
   one by one in a fresh module named ``submission``, announcing each so the grader
   can skip one that hangs; the probe talks to its parent on a socket of its own,
   which passes the messages on to the grader and kills the probe when it says
   ``ready`` (the probe never holds the control socket fork requests come on);
5. become the zygote: for each ``fork`` request (three pipe ends passed as
   descriptors) fork a worker that makes its private scratch folders, restricts
   itself to them with Landlock, stacks a seccomp filter that lets it signal only
   itself, loads the submission again, says ``loaded`` on its result pipe (a
   call's deadline starts then: the top-level code's time is no function's) and
   answers call requests on those pipes; kill a worker on request; reap everything.

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
_exit, _fork, _getpid = os._exit, os.fork, os.getpid


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
    if sock is None:
        return
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
        status_r, status_w = os.pipe()
        pid = os.fork()
        if pid:
            _mirror_child(pid, status_r)
        os.close(status_r)
        _STATUS_FD[0] = status_w
        libc.prctl(1, 9, 0, 0, 0)  # PR_SET_PDEATHSIG: process 1 dies with the process outside (and with it, all)
    return got


_STATUS_FD = [None]  # process 1 writes the zygote's wait status here for the process outside


def _mirror_child(pid, status_r):
    """Outside the PID namespace: wait for its process 1, then end as the submission's process ended.

    Process 1 (the namespace's init) reports the zygote's wait status on ``status_r``
    before it ends; without a report the status of process 1 itself is mirrored.
    """
    import signal

    for fd in range(3, 1024):  # keep only stdio: the pipes' other ends must see the child's EOF
        if fd != status_r:
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
    try:
        os.set_blocking(status_r, False)
        data = os.read(status_r, 64)
        if data.strip().lstrip(b"-").isdigit():
            status = int(data.strip())
    except (OSError, ValueError):
        pass
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
    _check(libc, libc.mount(b"tmpfs", os.fsencode(R), b"tmpfs", ro_fl, f"size={fs.get('root_size', '8m')},mode=0755".encode()),
           "root tmpfs")
    # the private /tmp first: folders of the interpreter, NumPy or SciPy under /tmp (a virtual environment
    # made there, a conda prefix) are bound inside it below instead of being hidden by it
    os.makedirs(f"{R}/tmp", mode=0o755)
    _check(libc, libc.mount(b"tmpfs", os.fsencode(f"{R}/tmp"), b"tmpfs", ro_fl,
                            f"size={fs.get('tmp_size', '64m')},nr_inodes=4096,mode=1777".encode()), "private /tmp")

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
        _check(libc, libc.mount(os.fsencode(f"/proc/self/fd/{fd}"), os.fsencode(dst), None, MS_BIND | MS_REC, None), f"bind {src}")
        if ro:
            st = os.statvfs(dst)
            keep = st.f_flag & (MS_NOSUID | MS_NODEV | MS_NOEXEC | MS_NOATIME | MS_NODIRATIME)
            if st.f_flag & 4096:  # ST_RELATIME
                keep |= MS_RELATIME
            _check(libc, libc.mount(None, os.fsencode(dst), None, MS_BIND | MS_REMOUNT | MS_RDONLY | keep, None),
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
            _check(libc, libc.mount(b"tmpfs", os.fsencode(R + h), b"tmpfs", ro_fl, b"size=64k,mode=0755"), f"hide {h}")
            hidden.append(h)
    for a in allow:
        if _under(a, bound) and not _under(a, hidden):
            continue  # already visible
        if pins.get(a) is not None:
            bind(a, pins[a])
    for h in hidden:
        libc.mount(None, os.fsencode(R + h), None, MS_REMOUNT | MS_RDONLY | ro_fl, None)
    for fd in pins.values():
        if fd is not None:
            os.close(fd)
    for d in ("tmp", "dev", "proc", "etc"):
        os.makedirs(f"{R}/{d}", mode=0o755, exist_ok=True)
    _check(libc, libc.mount(b"tmpfs", os.fsencode(f"{R}/dev"), b"tmpfs", MS_NOSUID, b"size=64k,mode=0755"), "/dev")
    for name in ("null", "zero", "full", "random", "urandom"):
        if os.path.exists(f"/dev/{name}"):
            mkpoint(f"{R}/dev/{name}", False)
            _check(libc, libc.mount(os.fsencode(f"/dev/{name}"), os.fsencode(f"{R}/dev/{name}"), None, MS_BIND, None),
                   f"/dev/{name}")
    os.makedirs(f"{R}/dev/shm", mode=0o755)
    _check(libc, libc.mount(b"tmpfs", os.fsencode(f"{R}/dev/shm"), b"tmpfs", ro_fl,
                            f"size={fs.get('shm_size', '16m')},nr_inodes=1024,mode=1777".encode()), "private /dev/shm")
    for name, target in (("fd", "/proc/self/fd"), ("stdin", "/proc/self/fd/0"), ("stdout", "/proc/self/fd/1"),
                         ("stderr", "/proc/self/fd/2")):
        os.symlink(target, f"{R}/dev/{name}")
    libc.mount(None, os.fsencode(f"{R}/dev"), None, MS_REMOUNT | MS_RDONLY | MS_NOSUID, None)
    _check(libc, libc.mount(b"proc", os.fsencode(f"{R}/proc"), b"proc", MS_NOSUID | MS_NODEV | MS_NOEXEC, None), "/proc")
    with open(f"{R}/etc/passwd", "w") as fh:
        fh.write("root:x:0:0:root:/tmp:/bin/false\nstudent:x:65534:65534:student:/tmp:/bin/false\n")
    with open(f"{R}/etc/group", "w") as fh:
        fh.write("root:x:0:\nstudent:x:65534:\n")
    os.makedirs(f"{R}/.old")
    _check(libc, libc.syscall(SYS_PIVOT_ROOT, os.fsencode(R), os.fsencode(f"{R}/.old")), "pivot_root")
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
    if got & NEWPID:
        _start_init(libc)  # returns in the zygote only; process 1 stays the namespace's init
        iso["init"] = True
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
    # a fresh, empty session keyring (not the grader's), then the system-call filter
    iso["session_keyring"] = _join_session_keyring(libc)
    if job.get("seccomp", True):
        err = _seccomp(_base_rules())
        iso["seccomp"] = err is None
        if err is not None:
            iso["seccomp_error"] = err
        else:
            iso["seccomp_backend"] = _SECCOMP_BACKEND[0]
    else:
        iso["seccomp"] = False
        iso["seccomp_error"] = "switched off"
    iso["landlock_abi"] = _landlock_abi()
    return libc


# --------------------------------------------------------------------------- process 1 of the namespace
def _start_init(libc):
    """Fork the zygote; this process (1 of the PID namespace) becomes a minimal init and never returns.

    Process 1 runs no submission code: it only reaps orphans and waits. It has no
    signal handlers (all ``SIG_DFL``), so the kernel drops every signal sent to it
    from inside the namespace, ``SIGKILL`` included; it has no capabilities, is not
    dumpable, and the seccomp filter of the processes below denies ``ptrace``. It
    ends, and the kernel kills everything in the namespace with it, when the
    zygote ends, when the grader closes its end of the control socket, or when the
    process outside (and so the grader: parent-death signals) goes away.
    """
    zpid = os.fork()
    if zpid == 0:
        libc.prctl(1, 9, 0, 0, 0)  # PR_SET_PDEATHSIG
        try:
            os.close(_STATUS_FD[0])
        except (OSError, TypeError):
            pass
        _STATUS_FD[0] = None
        return
    try:
        _init_loop(zpid, libc)
    finally:
        os._exit(0)


def _init_loop(zpid, libc):
    import select
    import signal

    status_w, ctl_fd = _STATUS_FD[0], _CTL_FD[0]
    for sig in signal.valid_signals():
        if sig not in (signal.SIGKILL, signal.SIGSTOP):
            try:
                signal.signal(sig, signal.SIG_DFL)
            except (OSError, ValueError):
                pass
    null = os.open("/dev/null", os.O_RDWR)
    for fd in (0, 1, 2):
        os.dup2(null, fd)
    keep = {0, 1, 2, status_w, ctl_fd}
    for fd in range(3, 1024):
        if fd not in keep:
            try:
                os.close(fd)
            except OSError:
                pass
    libc.prctl(38, 1, 0, 0, 0)  # PR_SET_NO_NEW_PRIVS
    libc.prctl(4, 0, 0, 0, 0)  # PR_SET_DUMPABLE 0
    _drop_capabilities(libc)
    zfd = os.pidfd_open(zpid)
    gone = select.POLLHUP | select.POLLERR | 0x2000  # POLLRDHUP
    poller = select.poll()
    poller.register(ctl_fd, 0x2000)
    poller.register(status_w, 0)  # POLLERR: the process outside closed its end (it is gone)
    poller.register(zfd, select.POLLIN)
    zstatus = None
    while zstatus is None:
        try:
            events = poller.poll(1000)
        except InterruptedError:
            events = []
        while True:  # reap the zygote, workers' orphans, anything reparented here
            try:
                pid, st = os.waitpid(-1, os.WNOHANG)
            except ChildProcessError:
                break
            if pid == 0:
                break
            if pid == zpid:
                zstatus = st
        if any(fd in (ctl_fd, status_w) and ev & gone for fd, ev in events):
            break
    if zstatus is not None:
        try:
            _write(status_w, str(zstatus).encode())
        except OSError:
            pass


_CTL_FD = [None]


# --------------------------------------------------------------------------- kernel context: keyrings, seccomp
def _syscall_numbers():
    """Native system-call numbers of the calls the filters name (x86_64 and aarch64)."""
    machine = os.uname().machine
    if machine in ("x86_64", "amd64"):
        return _NR_X86_64
    if machine in ("aarch64", "arm64"):
        return _NR_AARCH64
    return {}


_NR_X86_64 = {
    "keyctl": 250, "add_key": 248, "request_key": 249, "unshare": 272, "setns": 308, "clone": 56, "clone3": 435,
    "ptrace": 101, "bpf": 321, "perf_event_open": 298, "io_uring_setup": 425, "io_uring_enter": 426,
    "io_uring_register": 427, "mount": 165, "umount2": 166, "pivot_root": 155, "chroot": 161, "userfaultfd": 323,
    "process_vm_readv": 310, "process_vm_writev": 311, "kexec_load": 246, "kexec_file_load": 320,
    "init_module": 175, "finit_module": 313, "delete_module": 176, "open_by_handle_at": 304,
    "name_to_handle_at": 303, "fsopen": 430, "fsconfig": 431, "fsmount": 432, "fspick": 433, "open_tree": 428,
    "move_mount": 429, "mount_setattr": 442, "swapon": 167, "swapoff": 168, "reboot": 169, "acct": 163,
    "quotactl": 179, "pidfd_getfd": 438, "kcmp": 312, "syslog": 103, "vhangup": 153, "iopl": 172, "ioperm": 173,
    "modify_ldt": 154, "lookup_dcookie": 212, "shmget": 29, "shmat": 30, "shmctl": 31, "shmdt": 67, "semget": 64,
    "semop": 65, "semctl": 66, "semtimedop": 220, "msgget": 68, "msgsnd": 69, "msgrcv": 70, "msgctl": 71,
    "mq_open": 240, "mq_unlink": 241, "mq_timedsend": 242, "mq_timedreceive": 243, "mq_notify": 244,
    "mq_getsetattr": 245, "socket": 41, "socketpair": 53, "kill": 62, "tkill": 200, "tgkill": 234,
    "rt_sigqueueinfo": 129, "rt_tgsigqueueinfo": 297, "pidfd_send_signal": 424, "pidfd_open": 434,
    "personality": 135, "fcntl": 72, "ioctl": 16, "fanotify_init": 300, "quotactl_fd": 443, "setdomainname": 171,
    "sethostname": 170, "settimeofday": 164, "clock_settime": 227, "adjtimex": 159, "clock_adjtime": 305,
    "migrate_pages": 256, "move_pages": 279, "mbind": 237, "nfsservctl": 180, "uselib": 134,
    "memfd_create": 319, "memfd_secret": 447, "setxattr": 188, "lsetxattr": 189, "fsetxattr": 190,
    "setxattrat": 463, "setpriority": 141, "sched_setparam": 142, "sched_setscheduler": 144,
    "sched_setaffinity": 203, "sched_setattr": 314, "ioprio_set": 251,
}
_NR_AARCH64 = {
    "keyctl": 219, "add_key": 217, "request_key": 218, "unshare": 97, "setns": 268, "clone": 220, "clone3": 435,
    "ptrace": 117, "bpf": 280, "perf_event_open": 241, "io_uring_setup": 425, "io_uring_enter": 426,
    "io_uring_register": 427, "mount": 40, "umount2": 39, "pivot_root": 41, "chroot": 51, "userfaultfd": 282,
    "process_vm_readv": 270, "process_vm_writev": 271, "kexec_load": 104, "kexec_file_load": 294,
    "init_module": 105, "finit_module": 273, "delete_module": 106, "open_by_handle_at": 265,
    "name_to_handle_at": 264, "fsopen": 430, "fsconfig": 431, "fsmount": 432, "fspick": 433, "open_tree": 428,
    "move_mount": 429, "mount_setattr": 442, "swapon": 224, "swapoff": 225, "reboot": 142, "acct": 89,
    "quotactl": 60, "pidfd_getfd": 438, "kcmp": 272, "syslog": 116, "vhangup": 58, "lookup_dcookie": 18,
    "shmget": 194, "shmat": 196, "shmctl": 195, "shmdt": 197, "semget": 190, "semop": 193, "semctl": 191,
    "semtimedop": 192, "msgget": 186, "msgsnd": 189, "msgrcv": 188, "msgctl": 187, "mq_open": 180,
    "mq_unlink": 181, "mq_timedsend": 182, "mq_timedreceive": 183, "mq_notify": 184, "mq_getsetattr": 185,
    "socket": 198, "socketpair": 199, "kill": 129, "tkill": 130, "tgkill": 131, "rt_sigqueueinfo": 138,
    "rt_tgsigqueueinfo": 240, "pidfd_send_signal": 424, "pidfd_open": 434, "personality": 92,
    "fcntl": 25, "ioctl": 29, "fanotify_init": 262, "quotactl_fd": 443, "setdomainname": 162, "sethostname": 161,
    "settimeofday": 170,
    "clock_settime": 112, "adjtimex": 171, "clock_adjtime": 266, "migrate_pages": 238, "move_pages": 239,
    "mbind": 235, "memfd_create": 279, "memfd_secret": 447, "setxattr": 5, "lsetxattr": 6, "fsetxattr": 7,
    "setxattrat": 463, "setpriority": 140, "sched_setparam": 118, "sched_setscheduler": 119,
    "sched_setaffinity": 122, "sched_setattr": 274, "ioprio_set": 30,
}

#: what a numerical function never needs: kernel keyrings, namespaces, tracing, BPF, io_uring, mounts,
#: other processes' memory, kernel modules, SysV and POSIX IPC, socket pairs, anonymous memory files (memfd:
#: their pages count against no RLIMIT_AS and no tmpfs cap of the sandbox) and extended attributes (kernel memory
#: too; the tmpfs mounts also cap their inodes), clock and host settings, its own scheduling (a worker that
#: lowered its priority or narrowed its processors would wait for one on purpose, and the grader gives that
#: waiting back as the machine's: sandbox._Waiting); sockets
#: other than IPv4/IPv6 (UNIX, netlink, packet, AF_ALG ...: see _base_rules), which the network namespace
#: leaves without a route
DENIED = ("keyctl", "add_key", "request_key", "unshare", "setns", "ptrace", "bpf", "perf_event_open",
          "io_uring_setup", "io_uring_enter", "io_uring_register", "mount", "umount2", "pivot_root", "chroot",
          "userfaultfd", "process_vm_readv", "process_vm_writev", "kexec_load", "kexec_file_load", "init_module",
          "finit_module", "delete_module", "open_by_handle_at", "name_to_handle_at", "fsopen", "fsconfig",
          "fsmount", "fspick", "open_tree", "move_mount", "mount_setattr", "swapon", "swapoff", "reboot", "acct",
          "quotactl", "quotactl_fd", "pidfd_getfd", "kcmp", "syslog", "vhangup", "iopl", "ioperm", "modify_ldt",
          "lookup_dcookie", "shmget", "shmat", "shmctl", "shmdt", "semget", "semop", "semctl", "semtimedop",
          "msgget", "msgsnd", "msgrcv", "msgctl", "mq_open", "mq_unlink", "mq_timedsend", "mq_timedreceive",
          "mq_notify", "mq_getsetattr", "socketpair", "fanotify_init", "setdomainname", "sethostname",
          "settimeofday", "clock_settime", "adjtimex", "clock_adjtime", "migrate_pages", "move_pages", "mbind",
          "nfsservctl", "uselib", "personality", "memfd_create", "memfd_secret", "setxattr", "lsetxattr",
          "fsetxattr", "setxattrat", "setpriority", "sched_setparam", "sched_setscheduler", "sched_setaffinity",
          "sched_setattr", "ioprio_set")
#: namespace flags of clone(): a process may fork, not make new namespaces
CLONE_NS_FLAGS = (0x00020000, 0x02000000, 0x04000000, 0x08000000, 0x10000000, 0x20000000, 0x40000000)
EPERM, ENOSYS = 1, 38


def _base_rules():
    """Rules of the zygote's filter (inherited by every worker): ``(name, errno, [(arg, op, a, b)])``."""
    rules = [(name, EPERM, []) for name in DENIED]
    rules += [("clone", EPERM, [(0, "masked_eq", f, f)]) for f in CLONE_NS_FLAGS]
    rules.append(("clone3", ENOSYS, []))  # flags sit in memory a filter cannot read: C libraries fall back to clone
    rules.append(("socket", EPERM, [(0, "not_in", (2, 10), 0)]))  # AF_INET and AF_INET6 only
    return rules


def _worker_rules(pid):
    """Stacked on the base filter in every worker: it may signal itself only, and open no pidfds."""
    return [("kill", EPERM, [(0, "ne", pid, 0)]), ("tkill", EPERM, [(0, "ne", pid, 0)]),
            ("tgkill", EPERM, [(0, "ne", pid, 0)]), ("rt_sigqueueinfo", EPERM, [(0, "ne", pid, 0)]),
            ("rt_tgsigqueueinfo", EPERM, [(0, "ne", pid, 0)]), ("pidfd_send_signal", EPERM, []),
            ("pidfd_open", EPERM, [])] + [
        # no signal-driven I/O: F_SETOWN/F_SETOWN_EX/F_SETSIG and FIOSETOWN/SIOCSPGRP would have the kernel
        # signal another process (the zygote) for the worker; commands are 32-bit in the kernel
        (name, EPERM, [(1, "eq32", cmd, 0)])
        for name, cmd in (("fcntl", 8), ("fcntl", 15), ("fcntl", 10), ("ioctl", 0x8901), ("ioctl", 0x8902))] + [
        # no pipe grown beyond its default buffer (F_SETPIPE_SZ): kernel memory outside RLIMIT_AS
        ("fcntl", EPERM, [(1, "eq32", 1031, 0)])]


_SECCOMP_LIB = [None]
_SECCOMP_BACKEND = [None]


def _load_libseccomp():
    """libseccomp through ctypes (loaded before the child isolates itself); None when not installed."""
    import ctypes
    import ctypes.util

    for name in (ctypes.util.find_library("seccomp"), "libseccomp.so.2"):
        if not name:
            continue
        try:
            lib = ctypes.CDLL(name, use_errno=True)
        except OSError:
            continue
        lib.seccomp_init.restype = ctypes.c_void_p
        lib.seccomp_init.argtypes = [ctypes.c_uint32]
        lib.seccomp_rule_add_array.argtypes = [ctypes.c_void_p, ctypes.c_uint32, ctypes.c_int, ctypes.c_uint,
                                               ctypes.c_void_p]
        lib.seccomp_syscall_resolve_name.argtypes = [ctypes.c_char_p]
        lib.seccomp_load.argtypes = [ctypes.c_void_p]
        lib.seccomp_release.argtypes = [ctypes.c_void_p]
        lib.seccomp_attr_set.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_uint32]
        return lib
    return None


def _seccomp(rules):
    """Install a filter that returns the given errno for each rule (everything else allowed).

    Through libseccomp when it is installed (it adds the architecture check and
    resolves names); else a classic BPF program built here for x86_64 and aarch64.
    Returns None on success, else why it could not be installed.
    """
    lib = _SECCOMP_LIB[0]
    if lib is not None:
        err = _seccomp_libseccomp(lib, rules)
        if err is None:
            _SECCOMP_BACKEND[0] = "libseccomp"
            return None
    err2 = _seccomp_bpf(rules)
    if err2 is None:
        _SECCOMP_BACKEND[0] = "bpf"
        return None
    return err2 if lib is None else f"libseccomp: {err}; bpf: {err2}"


_OPS = {"ne": 1, "lt": 2, "le": 3, "eq": 4, "ge": 5, "gt": 6, "masked_eq": 7}


def _seccomp_libseccomp(lib, rules):
    import ctypes

    class ArgCmp(ctypes.Structure):
        _fields_ = [("arg", ctypes.c_uint), ("op", ctypes.c_int), ("datum_a", ctypes.c_uint64),
                    ("datum_b", ctypes.c_uint64)]

    ctx = lib.seccomp_init(0x7FFF0000)  # SCMP_ACT_ALLOW
    if not ctx:
        return "seccomp_init failed"
    try:
        lib.seccomp_attr_set(ctx, 4, 1)  # SCMP_FLTATR_CTL_TSYNC: every thread of the process
        expanded = []
        for name, errno, args in rules:
            if args and args[0][1] == "not_in":  # as several rules: below, between and above the allowed values
                arg, _, allowed, _ = args[0]
                lo, hi = min(allowed), max(allowed)
                expanded.append((name, errno, [(arg, "lt", lo, 0)]))
                expanded.append((name, errno, [(arg, "gt", hi, 0)]))
                expanded += [(name, errno, [(arg, "eq", v, 0)]) for v in range(lo + 1, hi) if v not in allowed]
            else:
                expanded.append((name, errno, args))
        for name, errno, args in expanded:
            nr = lib.seccomp_syscall_resolve_name(name.encode())
            if nr < 0:
                continue  # not a system call on this architecture
            arr = (ArgCmp * max(1, len(args)))()
            for k, (arg, op, a, b) in enumerate(args):
                if op == "eq32":  # the low 32 bits equal a: a masked comparison
                    arr[k] = ArgCmp(arg, _OPS["masked_eq"], 0xFFFFFFFF, a & 0xFFFFFFFF)
                elif op == "masked_eq":  # libseccomp: datum_a is the mask, datum_b the value
                    arr[k] = ArgCmp(arg, _OPS[op], a & 0xFFFFFFFFFFFFFFFF, b & 0xFFFFFFFFFFFFFFFF)
                else:
                    arr[k] = ArgCmp(arg, _OPS[op], a & 0xFFFFFFFFFFFFFFFF, 0)
            rc = lib.seccomp_rule_add_array(ctx, 0x00050000 | (errno & 0xFFFF), nr, len(args), arr)
            if rc < 0:
                return f"rule for {name}: {os.strerror(-rc)}"
        rc = lib.seccomp_load(ctx)
        if rc < 0:
            return f"seccomp_load: {os.strerror(-rc)}"
        return None
    finally:
        lib.seccomp_release(ctx)


def _seccomp_bpf(rules):
    """The same filter as a classic BPF program (architecture checked first; unknown ABIs are killed)."""
    import ctypes
    import struct

    machine = os.uname().machine
    if machine in ("x86_64", "amd64"):
        arch = 0xC000003E  # AUDIT_ARCH_X86_64
    elif machine in ("aarch64", "arm64"):
        arch = 0xC00000B7  # AUDIT_ARCH_AARCH64
    else:
        return f"no filter for the {machine} architecture"
    nrs = _syscall_numbers()
    LD, JEQ, JSET, JGE, RET, AND = 0x20, 0x15, 0x45, 0x35, 0x06, 0x54
    ALLOW, KILL = 0x7FFF0000, 0x80000000  # SECCOMP_RET_ALLOW, SECCOMP_RET_KILL_PROCESS
    prog = [(LD, 0, 0, 4), (JEQ, 1, 0, arch), (RET, 0, 0, KILL), (LD, 0, 0, 0)]
    if arch == 0xC000003E:  # x32 system calls (bit 30) share the x86_64 audit arch: refuse them
        prog += [(JGE, 0, 1, 0x40000000), (RET, 0, 0, 0x00050000 | ENOSYS)]
    for name, errno, args in rules:
        nr = nrs.get(name, -1)
        if nr < 0:
            continue
        ret = (RET, 0, 0, 0x00050000 | (errno & 0xFFFF))
        if not args:
            prog += [(JEQ, 0, 1, nr), ret]
            continue
        (arg, op, a, b), = args  # one comparison per rule is all the filters here use
        lo = 16 + 8 * arg  # seccomp_data.args[arg], low 32 bits (little-endian)
        if op == "masked_eq":
            # nr matches and (arg & a) == b, with a == b a single flag: JSET
            prog += [(JEQ, 0, 4, nr), (LD, 0, 0, lo), (JSET, 0, 1, a & 0xFFFFFFFF), ret, (LD, 0, 0, 0)]
        elif op == "eq32":
            # nr matches and the low 32 bits equal a: refuse
            prog += [(JEQ, 0, 3, nr), (LD, 0, 0, lo), (JEQ, 0, 1, a & 0xFFFFFFFF), ret, (LD, 0, 0, 0)]
        elif op == "not_in":
            vals = list(a)
            n = len(vals)
            # nr matches and the low 32 bits are none of vals: refuse; a match jumps to the reload of the number
            prog += [(JEQ, 0, n + 3, nr), (LD, 0, 0, lo)]
            prog += [(JEQ, n - k, 0, v & 0xFFFFFFFF) for k, v in enumerate(vals)]
            prog += [ret, (LD, 0, 0, 0)]
        elif op == "ne":
            # nr matches and the low 32 bits differ, or the high 32 bits are not those of a (sign-extended) int
            hi = (a >> 32) & 0xFFFFFFFF
            prog += [(JEQ, 0, 6, nr), (LD, 0, 0, lo), (JEQ, 0, 2, a & 0xFFFFFFFF), (LD, 0, 0, lo + 4),
                     (JEQ, 1, 0, hi), ret, (LD, 0, 0, 0)]
            # the jump over `ret` lands on the reload of the number
        else:
            return f"comparison {op!r} not built"
    prog.append((RET, 0, 0, ALLOW))
    code = b"".join(struct.pack("HBBI", c, jt, jf, k) for c, jt, jf, k in prog)
    buf = ctypes.create_string_buffer(code, len(code))

    class SockFprog(ctypes.Structure):
        _fields_ = [("len", ctypes.c_ushort), ("filter", ctypes.c_void_p)]

    fprog = SockFprog(len(prog), ctypes.cast(buf, ctypes.c_void_p))
    libc = _LIBC[0] or _libc()
    # seccomp(SECCOMP_SET_MODE_FILTER, SECCOMP_FILTER_FLAG_TSYNC, prog)
    nr = {"x86_64": 317, "amd64": 317}.get(machine, 277)
    if libc.syscall(nr, 1, 1, ctypes.byref(fprog)) != 0:
        return f"seccomp: {os.strerror(ctypes.get_errno())}"
    return None


def _join_session_keyring(libc):
    """keyctl(KEYCTL_JOIN_SESSION_KEYRING, NULL): a new anonymous session keyring; True when it held."""
    import ctypes

    nr = _syscall_numbers().get("keyctl")
    if nr is None:
        return False
    return libc.syscall(nr, ctypes.c_long(1), ctypes.c_void_p(None)) >= 0


# --------------------------------------------------------------------------- a private scratch space per worker
LL_RO = 1 | 4 | 8  # EXECUTE, READ_FILE, READ_DIR
LL_FILE = 1 | 2 | 4  # rights that apply to a file: EXECUTE, WRITE_FILE, READ_FILE (TRUNCATE from ABI 3)


def _landlock_abi():
    import ctypes

    libc = _LIBC[0] or _libc()
    v = libc.syscall(444, None, ctypes.c_size_t(0), ctypes.c_uint32(1))  # LANDLOCK_CREATE_RULESET_VERSION
    return int(v) if v > 0 else 0


def _private_scratch(wid, fs_paths, prefix=None):
    """Give this worker its own ``/tmp`` and ``/dev/shm`` folders and restrict it to them (Landlock).

    The worker makes ``/tmp/w<id>-<random>`` and ``/dev/shm/w<id>-<random>``, then
    restricts itself: read-only access to the system, Python and NumPy/SciPy trees
    and its own ``/proc/self``, read and write to a few devices and to its two
    folders, nothing else under ``/tmp``, ``/dev/shm`` or ``/proc`` (another
    worker's folders and ``/proc/<pid>`` entries included); from Landlock ABI 6
    on, also no signals to processes outside its own domain and no abstract UNIX
    sockets. ``TMPDIR`` and the working directory point at the private ``/tmp`` folder
    (``tempfile``, relative paths work; a fixed path such as ``/tmp/x`` is refused).
    Returns ``(abi, error)``.
    """
    import ctypes
    import tempfile

    abi = _landlock_abi()
    # an unguessable name: another worker can neither list /tmp nor find the folder to stat() what is in it
    # the sandbox's prefix first: without a mount namespace these folders are the host's, and the grader removes
    # them by it when the sandbox ends
    lead = f"{prefix}-" if isinstance(prefix, str) and prefix.isalnum() else ""
    tag = f"{lead}w{int(wid) if isinstance(wid, int) else 0}-{os.urandom(16).hex()}"
    tmp, shm = f"/tmp/{tag}", f"/dev/shm/{tag}"
    made = []
    for d in (tmp, shm):
        try:
            os.mkdir(d, 0o700)
            made.append(d)
        except OSError:
            pass
    if tmp in made:
        os.chdir(tmp)
        os.environ["TMPDIR"] = tmp
        tempfile.tempdir = tmp
    if abi < 1:
        return abi, "Landlock is not available on this kernel"
    libc = _LIBC[0] or _libc()
    handled = (1 << 13) - 1
    if abi >= 2:
        handled |= 1 << 13  # REFER
    file_rights = LL_FILE
    if abi >= 3:
        handled |= 1 << 14  # TRUNCATE
        file_rights |= 1 << 14

    class RulesetAttr(ctypes.Structure):
        _fields_ = [("fs", ctypes.c_uint64), ("net", ctypes.c_uint64), ("scoped", ctypes.c_uint64)]

    class PathBeneath(ctypes.Structure):
        _pack_ = 1
        _fields_ = [("allowed", ctypes.c_uint64), ("fd", ctypes.c_int32)]

    # TCP bind/connect refused too (ABI 4) where no network namespace cut the sandbox off already
    attr = RulesetAttr(handled, 3 if abi >= 4 and not _NETNS[0] else 0, 3 if abi >= 6 else 0)
    size = 24 if abi >= 6 else (16 if abi >= 4 else 8)
    rfd = libc.syscall(444, ctypes.byref(attr), ctypes.c_size_t(size), ctypes.c_uint32(0))
    if rfd < 0:
        return abi, f"landlock_create_ruleset: {os.strerror(ctypes.get_errno())}"
    try:
        def allow(path, rights):
            try:
                fd = os.open(path, os.O_PATH | os.O_CLOEXEC)
            except OSError:
                return
            try:
                if not os.path.isdir(f"/proc/self/fd/{fd}"):
                    rights &= file_rights
                rule = PathBeneath(rights, fd)
                libc.syscall(445, ctypes.c_int(rfd), ctypes.c_int(1), ctypes.byref(rule), ctypes.c_uint32(0))
            finally:
                os.close(fd)

        private = ("/tmp", "/dev", "/proc")
        for name in os.listdir("/"):
            if "/" + name not in private:
                allow("/" + name, LL_RO)
        allow("/proc", 8)  # READ_DIR: pids can be listed; files of other processes cannot be read
        for p in fs_paths:  # interpreter, NumPy/SciPy and library folders that live under /tmp or /dev
            if isinstance(p, str) and any(p == r or p.startswith(r + "/") for r in private) and os.path.exists(p):
                allow(p, LL_RO)
        allow("/proc/self", LL_RO)  # opened through the link: this process's own entry only
        for dev in ("null", "zero", "full"):
            allow(f"/dev/{dev}", file_rights)
        for dev in ("random", "urandom"):
            allow(f"/dev/{dev}", 4)
        for d in made:
            allow(d, handled)
        if libc.syscall(446, ctypes.c_int(rfd), ctypes.c_uint32(0)) != 0:
            return abi, f"landlock_restrict_self: {os.strerror(ctypes.get_errno())}"
    finally:
        os.close(rfd)
    return abi, None


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


def _send_ready(ctl, job, mod, notes, attempts, iso):
    """Tell the grader the submission is loaded: the notes, what each contract function is, the isolation."""
    import inspect

    info = {}
    for name in job.get("functions", []):
        fn = mod.__dict__.get(name)
        entry = {"defined": fn is not None, "callable": callable(fn)}
        # every field cut short: one datagram carries the message (a default argument of 60 000 items made the
        # signature 400 kB, the send failed and the loading looked like a crash)
        code = getattr(fn, "__code__", None)
        if code is not None:
            entry["filename"] = _short(str(getattr(code, "co_filename", "")), 300)
        entry["module"] = _short(getattr(fn, "__module__", None), 100) if fn is not None else None
        try:
            entry["signature"] = _short(str(inspect.signature(fn)), 1000) if callable(fn) else None
        except Exception:  # noqa: BLE001 - a default whose repr fails, a hostile __signature__
            entry["signature"] = None
        info[name] = entry
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except BaseException:  # noqa: BLE001
        pass
    _ctl_send(ctl, {"ev": "ready", "notes": [_short(n, 300) for n in notes[:200]], "functions": info,
                    "isolation": iso, "blocked": [_short(a, 300) for a in list(attempts)[:100]]})


def _load_submission(job, attempts, ctl):
    """Execute the submission statement by statement in a fresh module.

    Before each top-level statement the loader tells the grader which one it
    starts, so the grader can enforce a deadline per statement: a statement that
    hangs (an endless loop in a notebook cell) is skipped on the next load, as an
    interrupted cell would be, and the functions defined before and after it stay.
    ``job["cut"]`` (unit, statement), where the whole loading once ran out of time:
    that statement and every one after it are not run, as in a kernel interrupted there.
    """
    import ast
    import linecache
    import types

    mod = types.ModuleType("submission")
    mod.__file__ = job.get("display_name", "submission.py")
    # Jupyter's kernel gives every notebook `display`: a function that calls it (a debugging leftover) runs there,
    # and must run here too (its output is no part of the grade). A submission's own `display` replaces this one.
    mod.display = _display()
    sys.modules["submission"] = mod
    notes = []
    skip = {(int(u), int(s)) for u, s in job.get("skip", [])}
    cut = job.get("cut")
    cut = (int(cut[0]), int(cut[1])) if cut else None
    for k, unit in enumerate(job.get("units", [])):
        if cut is not None and k > cut[0]:
            break
        src, filename, label = unit["source"], unit["filename"], unit.get("label", unit["filename"])
        linecache.cache[filename] = (len(src), None, src.splitlines(True), filename)
        try:
            tree = ast.parse(src, filename=filename)
        except (SyntaxError, ValueError) as exc:
            notes.append(f"{label}: syntax error at line {getattr(exc, 'lineno', '?')}: "
                         f"{getattr(exc, 'msg', exc)} (skipped)")
            continue
        except (RecursionError, MemoryError):
            notes.append(f"{label}: too deeply nested for Python's parser (skipped)")
            continue
        for i, stmt in enumerate(tree.body):
            if cut is not None and (k, i) >= cut:
                break
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


def _display():
    """IPython's ``display``, which shows nothing here and returns None: made in a namespace of its own, so that
    its ``__globals__`` lead nowhere (not to the runner's module)."""
    ns = {}
    exec("def display(*objs, **kwargs):\n    return None\n", ns)  # noqa: S102 - a constant
    return ns["display"]


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


def _worker(job, ctl, fds, mod, attempts, npx, hook_busy, wid=0):
    """A fresh process forked from the loaded submission: serves calls on its own pipes.

    Before the first call it gets its own scratch folders and a Landlock domain
    (:func:`_private_scratch`), and a second seccomp filter that lets it signal only itself.
    """
    import resource

    req_fd, res_fd, out_fd = fds
    if ctl is not None:
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
    _restore_signals()
    if job.get("scratch", True):
        fs = job.get("fs") or {}
        paths = list(fs.get("python", [])) + list(fs.get("allow", [])) + list(sys.path)
        paths += [sys.prefix, sys.base_prefix, sys.exec_prefix]
        _private_scratch(wid, paths, job.get("scratch_prefix"))
    if job.get("seccomp", True) and _SECCOMP_ON[0]:
        _seccomp(_worker_rules(_getpid()))
    if mod is None:  # fork, isolate, then load: nothing the submission does at load time outlives this worker
        _close_fds_but(req_fd, res_fd)
        mod = _quiet_load(job, attempts)
    # the grader starts a call's deadline only now: the top-level code that just ran again is no function's time
    _send(res_fd, {"status": "loaded"})
    _run_then_exit(_serve, job, req_fd, res_fd, mod, attempts, npx)


def _close_fds_but(*keep):
    """Close every descriptor but 0-2 and ``keep``."""
    lo = 3
    for fd in sorted(set(k for k in keep if k >= 3)):
        if fd > lo:
            os.closerange(lo, fd)
        lo = fd + 1
    os.closerange(lo, 1 << 20)


def _quiet_load(job, attempts):
    """Load the submission in a worker: no statement events, what it prints while loading discarded."""
    saved = os.dup(1), os.dup(2)
    null = os.open("/dev/null", os.O_WRONLY)
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except BaseException:  # noqa: BLE001
        pass
    os.dup2(null, 1)
    os.dup2(null, 2)
    os.close(null)
    try:
        mod, _ = _load_submission(job, attempts, None)
    finally:
        try:
            sys.stdout.flush()
            sys.stderr.flush()
        except BaseException:  # noqa: BLE001
            pass
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        os.close(saved[0])
        os.close(saved[1])
    del attempts[:]  # refusals while loading were reported by the probe
    return mod


def _probe(job, ctl, attempts, npx, hook_busy):
    """A throwaway child that loads the submission once (statement events, ``ready``) with a worker's isolation.

    ``ctl`` is the probe's own socket to its parent, which passes the messages on to the grader and ends the
    probe when ``ready`` comes: the probe never holds the control socket that fork requests arrive on.
    """
    import inspect

    import resource

    nproc = int(job.get("limits", {}).get("nproc", 0))
    try:
        resource.setrlimit(resource.RLIMIT_NPROC, (nproc, nproc))
    except (ValueError, OSError):
        pass
    if job.get("scratch", True):
        fs = job.get("fs") or {}
        paths = list(fs.get("python", [])) + list(fs.get("allow", [])) + list(sys.path)
        paths += [sys.prefix, sys.base_prefix, sys.exec_prefix]
        _private_scratch(0, paths, job.get("scratch_prefix"))
    if job.get("seccomp", True) and _SECCOMP_ON[0]:
        _seccomp(_worker_rules(_getpid()))
    _close_fds_but(ctl.fileno())
    mod, notes = _load_submission(job, attempts, ctl)
    _send_ready(ctl, job, mod, notes, attempts, _PROBE_ISO[0])
    _exit(0)


def _relay_probe(pid, probe_ctl, ctl, hook_busy, iso):
    """Pass the probe's messages on to the grader until ``ready``; then end the probe and return True.

    The probe ran submission code, so after its ``ready`` it is killed (SIGKILL) and reaped before the
    zygote serves a fork: whatever it left running cannot take requests or outlive the loading. Returns
    False when the probe's socket closed first (the probe ended while loading).
    """
    import signal

    while True:
        try:
            data = probe_ctl.recv(1 << 20)
        except InterruptedError:
            continue
        except OSError:
            data = b""
        ready = False
        if data:
            try:
                msg = _loads(data.decode("utf-8"))
                ready = msg.get("ev") == "ready"
                if ready:  # which protections hold is this process's word, never the submission's
                    msg["isolation"] = iso
                    data = _dumps(msg, allow_nan=True, separators=(",", ":")).encode("utf-8")
            except (ValueError, AttributeError, RecursionError, TypeError):
                pass
        if ready or not data:  # a probe that closed its socket but lives on is ended as well: it is reaped next
            hook_busy[0] = True  # the runner's own act, not the submission's (the audit hook refuses os.kill)
            try:
                os.kill(pid, signal.SIGKILL)  # not yet reaped: the pid is still the probe's
            except OSError:
                pass
            finally:
                hook_busy[0] = False
        if not data:
            return False
        try:
            ctl.send(data)
        except OSError:
            pass
        if ready:
            return True


_PROBE_ISO = [None]


_SECCOMP_ON = [False]
_NETNS = [False]
_SAVED_SIGNALS = {}
#: signals that end a process by default and that the zygote ignores (a worker cannot end it with them)
_ZYGOTE_IGNORES = ("SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT", "SIGUSR1", "SIGUSR2", "SIGALRM", "SIGVTALRM",
                   "SIGPROF", "SIGPIPE", "SIGXCPU", "SIGTRAP", "SIGIO", "SIGPWR", "SIGSTKFLT", "SIGTSTP", "SIGTTIN",
                   "SIGTTOU")


def _ignore_signals():
    """In the zygote: ignore catchable signals (handlers a submission set while loading are put back in workers)."""
    import signal

    for name in _ZYGOTE_IGNORES:
        sig = getattr(signal, name, None)
        if sig is None:
            continue
        try:
            _SAVED_SIGNALS[sig] = signal.getsignal(sig)
            signal.signal(sig, signal.SIG_IGN)
        except (OSError, ValueError, TypeError):
            pass


def _restore_signals():
    import signal

    for sig, handler in _SAVED_SIGNALS.items():
        try:
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
        except (OSError, ValueError, TypeError):
            pass


def _run_then_exit(fn, *args):
    """Run ``fn(*args)``, flush stdout whatever happened, and end the process without cleanup."""
    try:
        fn(*args)
    finally:
        try:
            sys.stdout.flush()
        except BaseException:  # noqa: BLE001
            pass
        _exit(0)


_LIBC = [None]


def _zygote(job, ctl, mod, attempts, npx, hook_busy):
    """The zygote after loading: forks one worker per request, kills workers on request.

    Requests arrive on the control socket: ``fork`` (with the worker's three pipe
    ends passed as descriptors), ``kill`` and ``exit``. A worker is reaped as soon
    as it ends. Catchable signals that end a process are ignored here (workers get the handlers back).
    """
    import array
    import resource
    import select
    import signal
    import socket

    workers = {}  # id -> (pid, pidfd, the result pipe's write end: the exit status goes there)
    _ignore_signals()
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
                    pid = _fork()
                finally:
                    hook_busy[0] = False
            except OSError:
                # the machine's doing (a process limit, memory): the worker's pipes are closed with not a byte
                # written, which no worker can bring about (the zygote holds the result pipe too, and writes on it
                # when a worker ends); the grader reads that as a worker never started
                pid = -1
            if pid == 0:
                hook_busy[0] = False
                for _, pfd, rfd in workers.values():
                    for f in (pfd, rfd):
                        try:
                            os.close(f)
                        except OSError:
                            pass
                _worker(job, ctl, fds, mod, attempts, npx, hook_busy, wid)
            keep = None
            if pid > 0:
                try:
                    workers[wid] = (pid, os.pidfd_open(pid), fds[1])
                    keep = fds[1]
                except OSError:  # a worker the zygote cannot watch (and report on) is not left to run
                    try:
                        os.kill(pid, signal.SIGKILL)
                        os.waitpid(pid, 0)
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
    os.umask(0o022)  # the grader's umask (027, 077) would make the minimal root's folders unreadable after the uid drop
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
    import array, ast, ctypes, ctypes.util, inspect, linecache, random, resource, select, signal, stat, struct, tempfile, time, traceback, types  # noqa: E401,F401,E501

    npx = frozen_numpy(np)
    # the probe's own socket to this process (made now: the filter installed while isolating refuses socketpair)
    probe_pair = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET) if job.get("fork_then_load", True) else None
    iso = {}
    _CTL_FD[0] = ctl_fd
    _LIBC[0] = _libc_early
    # seccomp: True (libseccomp when installed, else the filter built here), "bpf" (the filter built here), False
    _SECCOMP_LIB[0] = _load_libseccomp() if job.get("seccomp", True) is True else None
    if job.get("isolate", True):
        _LIBC[0] = _isolate(job, iso, np)
    _SECCOMP_ON[0] = bool(iso.get("seccomp"))
    _NETNS[0] = bool(iso.get("netns"))
    attempts = []
    hook_busy = [False]
    if job.get("audit", True):
        hook_busy = _install_audit_hook(job.get("blocked_modules", []), job.get("blocked_paths", []), attempts,
                                        processes=job.get("block_processes", True))
    iso["audit_hook"] = bool(job.get("audit", True))
    if job.get("fork_then_load", True):
        # the zygote never runs submission code: a probe child loads it once for the grader (statement deadlines,
        # the ready message, passed on by _relay_probe, which then ends it); each worker loads it again after it
        # has isolated itself
        _PROBE_ISO[0] = iso
        probe_ctl, probe_child = probe_pair
        try:  # as before each fork of a worker (the uid's process count may be capped at its soft limit)
            import resource

            resource.setrlimit(resource.RLIMIT_NPROC, (resource.getrlimit(resource.RLIMIT_NPROC)[1],) * 2)
        except (ValueError, OSError):
            pass
        hook_busy[0] = True
        try:
            pid = _fork()
        finally:
            hook_busy[0] = False
        if pid == 0:
            probe_ctl.close()
            _run_then_exit(_probe, job, probe_child, attempts, npx, hook_busy)
        probe_child.close()
        ready = _relay_probe(pid, probe_ctl, ctl, hook_busy, iso)
        probe_ctl.close()
        code = 1
        try:
            code = os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])
        except (ChildProcessError, ValueError):
            pass
        if not ready:  # the probe ended while loading (os._exit, a signal): the sandbox ends the same way
            if code < 0:
                import signal

                try:
                    signal.signal(-code, signal.SIG_DFL)
                    os.kill(_getpid(), -code)
                except (OSError, ValueError):
                    pass
                _exit(1)
            _exit(code)
        _zygote(job, ctl, None, attempts, npx, hook_busy)
        return
    mod, notes = _load_submission(job, attempts, ctl)
    _send_ready(ctl, job, mod, notes, attempts, iso)
    _zygote(job, ctl, mod, attempts, npx, hook_busy)


if __name__ == "__main__":
    _run_then_exit(main, sys.argv)
