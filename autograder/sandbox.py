"""Running untrusted submission code: one sandbox per submission, one fresh worker per function.

A :class:`Sandbox` is one Python process (``python -I -S autograder/_runner.py``)
that isolates itself and then serves as a *zygote* that never runs submission
code: a throwaway child (the probe) loads the submission once for the grader
(statement deadlines, the functions it defines) and ends; for every contract
function (and after every crash or timeout) the grader asks the zygote to fork a
fresh :class:`Worker`, which isolates itself, closes every descriptor but its own
pipes, loads the submission again and answers calls on its own pipes. The
grader's process only sends arguments and reads back plain arrays; it never
imports or executes submission code, and expected values are computed only here.

Before it grades (``grade``, ``batch``, ``gradescope``, and ``python -m
autograder selfcheck``), the grader checks its own sandbox
(:func:`check_sandbox`): a probe that imports NumPy and SciPy wherever the
grader's interpreter finds them and runs one known-correct call must give the
known answer, else grading stops with exit status 3 and no results at all (an
environment failure is the grader's fault, never the student's).

What isolates the submission (the runner applies the OS-level parts to itself
before the first line of submission code runs; see ``_runner.py``):

* mount, PID, network, IPC and UTS namespaces, and a minimal root built from a
  tmpfs: read-only binds of the system libraries, the Python standard library, the
  NumPy and SciPy package folders and the folders of the shared libraries they load
  (a conda prefix's ``lib``); a private ``/tmp`` (mounted first, so an environment
  under ``/tmp`` is bound inside it) and ``/dev/shm`` with a size cap; a fresh
  ``/proc``; ``/dev/null``, ``zero``, ``urandom``. The reference (``slamlib``), the
  tests (``autograder``), the bundle, the batch folder and other submissions are not
  in that root;
* process 1 of the PID namespace is a minimal init that runs no submission code:
  it has no signal handlers (the kernel drops every signal sent to it from inside,
  ``SIGKILL`` included), no capabilities, is not dumpable, and it ends, taking every
  process of the namespace with it, when the zygote ends, when the grader closes
  the control socket or when the grader dies (parent-death signals up the chain):
  nothing a submission starts (``setsid``, double forks, a cleared parent-death
  signal) outlives its grading;
* a seccomp filter (through libseccomp when installed, else a BPF program built by
  the runner for x86_64 and aarch64, architecture checked) installed before the
  submission loads: kernel keyrings, new namespaces (``unshare``, ``setns``,
  namespace flags of ``clone``; ``clone3`` answers ENOSYS), ``ptrace``, ``bpf``,
  ``perf_event_open``, io_uring, mounts, ``userfaultfd``, other processes' memory,
  kernel modules, SysV/POSIX IPC, socket pairs and sockets other than IPv4/IPv6
  are refused with EPERM; each worker stacks a second filter that lets it signal
  itself only (nor have the kernel signal another process for it: no ``F_SETOWN``,
  ``F_SETOWN_EX``, ``F_SETSIG``, ``FIOSETOWN``, ``SIOCSPGRP``). The sandbox first joins a fresh session keyring;
* each worker has a private scratch space: its own ``/tmp/w<id>-<pid>`` and
  ``/dev/shm/w<id>-<pid>`` (its working directory and ``TMPDIR``), and a Landlock
  domain that gives it read-only access to the system and Python trees, its own
  ``/proc/self``, a few devices, and nothing else under ``/tmp``, ``/dev/shm`` or
  ``/proc``: no file or shared memory passes between functions. From Landlock ABI 6
  the domain also keeps its signals and abstract UNIX sockets to itself;
* a unique unprivileged uid/gid when the grader runs as root, drawn at random from a
  pool that never repeats while the grader runs (else no capabilities in a user
  namespace), ``no_new_privs``, not dumpable, a parent-death signal;
* resource limits (CPU, 2 GiB of address space, file size, no new processes in a
  worker, no core dumps);
* an audit hook as a second line (imports of ``slamlib``/``autograder``, reads of
  their files, processes, sockets, ``ctypes`` lookups);
* a wall-clock deadline per call and per top-level statement while loading,
  enforced here; output read through pipes with a byte cap; results through a
  framed format of JSON and raw array bytes that this module validates (no pickles).

Which protections hold on which host (each line of :func:`describe_isolation`
names what held; ``selfcheck`` prints them, and every report for the course staff
carries them):

==========================  ================================================================
host                        what holds
==========================  ================================================================
namespaces allowed          minimal root, private ``/tmp``/``/dev/shm``, PID namespace with
(root, or unprivileged      the init above (no survivors), no network; as root also a fresh
user namespaces)            uid per submission; as a user, no capabilities in a user namespace
no namespaces (a container  a separate uid when root (the reference unreadable where file
with a default seccomp      permissions say so: the bundle's ``setup.sh``); no PID namespace,
profile)                    so a process a submission detaches with ``setsid`` may outlive
                            grading; files not isolated
seccomp available           the filter above (kernel >= 3.5; with libseccomp or without)
Landlock available          per-worker scratch folders (kernel >= 5.13, ABI >= 1); signal
                            and abstract-socket scoping from ABI 6 (kernel >= 6.12); without
                            it, the seccomp filter still keeps workers from signalling anything
                            but themselves, and workers of one submission share ``/tmp``
cgroups                     not used: the PID namespace is what ends every process, and
                            rlimits bound memory, CPU and processes
==========================  ================================================================

Nothing the submission makes at load time (shared memory, pipes, threads, hooks,
replaced runner helpers, processes) is shared between its workers or reaches the
zygote: each worker loads it after its own isolation is in place. Top-level code
therefore runs once in the probe and once per worker; its time counts against the
worker's first call.
"""

from __future__ import annotations

import itertools
import json
import math
import os
import selectors
import signal
import site
import socket
import stat
import subprocess
import sys
import sysconfig
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import wire
from . import fill_standard_fds
from .submission import MAX_CODE
from .wire import (ProtocolError, RngSeed, clean_text, control_message, encode_args, pack_frame, parse_result_frame,
                   read_reply)

__all__ = ["Limits", "Sandbox", "Worker", "CallOutcome", "ChildFailed", "RngSeed", "isolation_report",
           "describe_isolation", "protection_level", "check_sandbox", "require_sandbox", "SandboxBroken",
           "WorkerNotStarted", "run_delay"]

_PKG_DIR = Path(__file__).resolve().parent
#: The child's script; it loads ``wire.py`` from the same folder before it isolates itself.
RUNNER = str(_PKG_DIR / "_runner.py")
_counter = itertools.count()
_counter_lock = threading.Lock()


@dataclass(frozen=True)
class Limits:
    """Resource limits and time budgets of one submission's sandbox.

    Attributes
    ----------
    call_timeout : float or None
        Upper bound (seconds) on every call's wall time; a test's own timeout
        applies when smaller. ``None`` keeps the tests' timeouts.
    import_timeout : float
        Wall time allowed to load the submission (all its top-level code). When it runs out, the statement under
        way and every one after it are left out, as in an interrupted kernel, and the submission is loaded once
        more without them; that loading, and each worker's, may then take twice this time.
    statement_timeout : float
        Wall time allowed to one top-level statement (a notebook cell's loop); a
        statement over it is skipped and the submission loaded again without it.
    test_budget : float or None
        Wall time of one test (all its calls); ``None`` takes the exercise's.
    submission_budget : float or None
        Wall time of the whole grading; ``None`` takes the exercise's.
    memory : int
        ``RLIMIT_AS`` in bytes.
    output : int
        Bytes of stdout+stderr a worker (or the loading) may write before it is killed.
    file_size : int
        ``RLIMIT_FSIZE`` in bytes.
    tmp_size : str
        Size of the private ``/tmp`` (tmpfs), which caps what a submission can write.
    cpu : int
        ``RLIMIT_CPU`` in seconds (a backstop: calls have wall-clock deadlines).
    network : bool
        Put the sandbox in a new network namespace when possible.
    filesystem : bool
        Build the minimal root (mount namespace) when possible.
    audit : bool
        Install the audit hook.
    block_processes : bool
        Let the audit hook refuse new processes (tests switch it off to check
        that the OS limits alone contain a fork).
    seccomp : bool or "bpf"
        Install the system-call filters (zygote and workers): through libseccomp
        when it is installed, else (and with ``"bpf"``) as a BPF program built by the runner.
    code : int
        Characters of code the grader reads and parses, in its own process, where none of
        these limits applies (:data:`autograder.submission.MAX_CODE`).
    """

    call_timeout: float | None = None
    import_timeout: float = 30.0
    statement_timeout: float = 10.0
    test_budget: float | None = None
    submission_budget: float | None = None
    memory: int = 2 << 30
    output: int = 1 << 20
    file_size: int = 16 << 20
    tmp_size: str = "64m"
    cpu: int = 600
    network: bool = True
    filesystem: bool = True
    audit: bool = True
    block_processes: bool = True
    seccomp: bool = True
    code: int = MAX_CODE

    def __post_init__(self):
        # a limit of the wrong kind or sign would be coerced into a grading of the wrong strictness
        for name in ("call_timeout", "test_budget", "submission_budget", "import_timeout", "statement_timeout"):
            value = getattr(self, name)
            if value is None and name in ("call_timeout", "test_budget", "submission_budget"):
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise ValueError(f"Limits.{name}: expected a positive, finite number of seconds"
                                 f"{' or None' if name not in ('import_timeout', 'statement_timeout') else ''}, "
                                 f"got {value!r}")
        for name in ("memory", "output", "file_size", "cpu", "code"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"Limits.{name}: expected a positive integer, got {value!r}")


@dataclass
class CallOutcome:
    """What one call of a student function produced.

    ``status`` is ``"ok"`` (returned; ``returned`` holds the value), ``"error"``
    (raised; ``error`` and ``where`` say what), ``"timeout"``, ``"crashed"``
    (the process died), ``"output"`` (printed too much), ``"protocol"`` (the
    result channel was corrupted) or ``"skipped"`` (not run, see ``error``).
    """

    status: str
    returned: object = None
    error: str | None = None
    where: str | None = None
    mutated: list = field(default_factory=list)
    blocked: list = field(default_factory=list)
    output: str = ""
    elapsed: float = 0.0
    budget: str | None = None  # "test" or "submission" when a time budget, not the call's limit, ran out
    waited: float = 0.0  # seconds the machine kept the worker waiting for a processor during the call (no one's time)


class ChildFailed(Exception):
    """The sandbox could not be started or the submission not loaded (carries a CallOutcome)."""

    def __init__(self, outcome, reason=None):
        super().__init__(outcome.error)
        self.outcome = outcome
        self.reason = reason  # why a loading failed: "timeout", "statement", "protocol", "eof"


# --------------------------------------------------------------------------- what the sandbox may see
def _mapped_files():
    """The files mapped into this process (``/proc/self/maps``) that exist, as the file system names them: read as
    bytes (a path need not be text in the locale's encoding: an install under ``/opt/pé th`` in the C locale),
    a path with spaces kept whole."""
    try:
        with open("/proc/self/maps", "rb") as fh:
            lines = fh.read().splitlines()
    except OSError:
        return []
    out = []
    for line in lines:
        parts = line.split(None, 5)
        path = os.fsdecode(parts[5].strip()) if len(parts) == 6 else ""
        if path.startswith("/") and path not in out and os.path.exists(path):
            out.append(path)
    return out


def _real(p):
    return os.path.realpath(p)


def _package_dirs(name):
    try:
        m = __import__(name)
    except ImportError:
        return []
    d = Path(m.__file__).resolve().parent
    out = [str(d)]
    libs = d.parent / f"{name}.libs"
    if libs.is_dir():
        out.append(str(libs.resolve()))
    return out


def _site_paths():
    out = []
    for mod in ("numpy", "scipy"):
        for d in _package_dirs(mod)[:1]:
            p = str(Path(d).parent)
            if p not in out:
                out.append(p)
    return out


def _blocked_paths():
    paths = [str(_PKG_DIR)]
    try:
        import slamlib

        paths.append(str(Path(slamlib.__file__).resolve().parent))
    except ImportError:
        pass
    return paths


def fs_spec(limits):
    """What the minimal root holds: system trees, the stdlib, NumPy/SciPy; what it hides."""
    stdlib = _real(os.path.dirname(os.__file__))
    python = [stdlib]
    for key in ("stdlib", "platstdlib"):
        p = sysconfig.get_paths().get(key)
        if p and os.path.isdir(p):
            python.append(_real(p))
    for p in sys.path:
        if p and (p.endswith(".zip") or p.endswith("lib-dynload")) and os.path.exists(p):
            python.append(_real(p))
    # a shared libpython outside the system trees (a Python built under /opt or /root)
    python += [_real(path) for path in _mapped_files() if "libpython" in os.path.basename(path)]
    hide = set()
    try:
        hide.update(site.getsitepackages())
    except AttributeError:
        pass
    try:
        hide.add(site.getusersitepackages())
    except AttributeError:
        pass
    hide.update(p for p in sys.path if p and os.path.isdir(p))
    for base in (sys.prefix, sys.base_prefix, sys.exec_prefix):
        for sub in ("site-packages", "dist-packages"):
            hide.add(os.path.join(stdlib, sub))
            hide.add(os.path.join(base, "lib", os.path.basename(stdlib), sub))
    hide.add("/usr/lib/python3/dist-packages")
    for p in _blocked_paths():
        hide.add(p)
        hide.add(str(Path(p).parent))
    system = ["/usr", "/lib", "/lib64", "/lib32", "/libx32", "/bin", "/sbin", "/etc/ld.so.cache"]
    python.extend(_library_dirs(system, hide))
    keep = set(python)
    hide = sorted({_real(h) for h in hide if h and os.path.isdir(h)} - keep - {"/"})
    # a hidden folder that contains the stdlib would hide Python itself
    hide = [h for h in hide if not any(k == h or k.startswith(h + "/") for k in keep)]
    allow = _package_dirs("numpy") + _package_dirs("scipy")
    return {
        "system": system,
        "python": list(dict.fromkeys(python)),
        "allow": allow,
        "hide": hide,
        "tmp_size": limits.tmp_size,
        "shm_size": "16m",
        "root_size": "8m",
    }


def _library_dirs(system, site_dirs):
    """Folders of the shared libraries NumPy and SciPy load that lie outside the system trees.

    A conda prefix keeps OpenBLAS, libgfortran and friends in ``$PREFIX/lib``,
    beside (not inside) ``site-packages``: they are bound read-only too, so the
    sandbox imports NumPy and SciPy wherever the grader's interpreter finds them.
    Folders inside a site-packages folder (other packages) are left out; NumPy's
    and SciPy's own folders are bound through ``allow``.
    """
    for name in ("scipy.linalg", "scipy.sparse", "scipy.special"):
        try:
            __import__(name)
        except ImportError:
            pass
    sites = [_real(p) for p in site_dirs if p and os.path.isdir(p)]
    blocked = [_real(p) for p in _blocked_paths()]
    out = []
    for path in _mapped_files():
        if ".so" not in os.path.basename(path):
            continue
        d = os.path.dirname(_real(path))
        if any(d == r or d.startswith(r.rstrip("/") + "/") for r in system + sites + blocked):
            continue
        if d not in out:
            out.append(d)
    return out


SITE_PATHS = _site_paths()
BLOCKED_MODULES = ("slamlib", "autograder")
BLOCKED_PATHS = _blocked_paths()
_FS_CACHE = {}


def _fs(limits):
    key = limits.tmp_size
    if key not in _FS_CACHE:
        _FS_CACHE[key] = fs_spec(limits)
    return _FS_CACHE[key]


#: uids handed to sandboxes by this process: never handed out twice
_USED_IDS = set()
_ID_LOW, _ID_HIGH = 1 << 24, (1 << 31) - 1


def _child_ids():
    """A uid/gid for one sandbox, from a pool that does not repeat while the grader runs.

    Drawn uniformly from 2**24 .. 2**31 - 2 by the operating system's random
    source (not from the grader's pid or a counter, which repeat across grader
    processes), and never twice in one process; a ``batch`` run's worker processes
    draw independently (a repeat among 50 submissions has a probability near 1e-6).
    Nothing the kernel keeps per uid (user keyrings, the process count) is
    inherited from an earlier sandbox.
    """
    import secrets

    with _counter_lock:
        while True:
            uid = _ID_LOW + secrets.randbelow(_ID_HIGH - _ID_LOW)
            if uid not in _USED_IDS:
                _USED_IDS.add(uid)
                return uid, uid


def _env():
    return {
        "PATH": "/usr/bin:/bin",
        "HOME": "/tmp",
        "TMPDIR": "/tmp",
        "LANG": "C.UTF-8",
        "LC_ALL": "C.UTF-8",
        "MPLBACKEND": "Agg",
        "OMP_NUM_THREADS": "1",
        "OPENBLAS_NUM_THREADS": "1",
        "MKL_NUM_THREADS": "1",
        "NUMEXPR_NUM_THREADS": "1",
        "PYTHONHASHSEED": "0",
    }


def _exit_text(code):
    if code is None:
        return "no exit status"
    if code < 0:
        try:
            return f"killed by signal {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit status {code}"


# --------------------------------------------------------------------------- the sandbox (zygote)
def _remove_scratch(prefix):
    """Remove the scratch folders a sandbox's processes made in the host's ``/tmp`` and ``/dev/shm`` (only without
    a mount namespace: with one, they were in its own tmpfs). Folders only, never followed through a link.

    ``rm -rf`` walks a tree of any depth without recursion (``shutil.rmtree`` of Python 3.11 recurses once per
    level: 5000 nested folders raised RecursionError out of the grading) and never follows a link; whatever fails
    here leaves folders behind, never a grading.
    """
    try:
        for top in ("/tmp", "/dev/shm"):
            try:
                names = [n for n in os.listdir(top) if n.startswith(prefix + "-")]
            except OSError:
                continue
            paths = [os.path.join(top, n) for n in names if stat.S_ISDIR(os.lstat(os.path.join(top, n)).st_mode)]
            if paths:
                subprocess.run(["rm", "-rf", "--one-file-system", "--", *paths], stdin=subprocess.DEVNULL,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=120, check=False)
    except Exception:  # noqa: BLE001 - the host's litter, never the grading's failure
        pass


# --------------------------------------------------------------------------- time the machine kept a process waiting
#: A call may run this many times its limit longer when the machine kept its worker waiting for a processor.
MAX_STRETCH = 3.0


def _descendants(pid):
    """Host process ids below ``pid`` (its children, theirs, ...), from ``/proc``; empty when it cannot tell."""
    out, todo = [], [int(pid)]
    while todo and len(out) < 64:
        p = todo.pop()
        try:
            with open(f"/proc/{p}/task/{p}/children", "rb") as fh:
                kids = [int(k) for k in fh.read().split()]
        except (OSError, ValueError):
            continue
        out.extend(kids)
        todo.extend(kids)
    return out


def _scheduling(pid):
    """``(nice, allowed processors)`` of a process, from ``/proc``; None when it cannot tell."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            stat_line = fh.read()
        nice = int(stat_line[stat_line.rindex(b")") + 2:].split()[16])  # field 19 of stat(5)
        with open(f"/proc/{pid}/status", "rb") as fh:
            cpus = next((ln.split(b":", 1)[1].strip() for ln in fh if ln.startswith(b"Cpus_allowed_list:")), None)
        return nice, cpus
    except (OSError, ValueError, IndexError):
        return None


def thread_delay():
    """Seconds the calling thread of the grader has spent runnable but waiting for a processor (the kernel's
    ``/proc/self/task/<tid>/schedstat``), or None where the kernel does not say."""
    try:
        with open(f"/proc/self/task/{threading.get_native_id()}/schedstat", "rb") as fh:
            return int(fh.read().split()[1]) / 1e9
    except (OSError, ValueError, IndexError):
        return None


def _delays(pids):
    """``{pid: seconds}`` each process has spent runnable but waiting for a processor, for those the kernel says.

    A process that lowered its own priority or narrowed its processors below the grader's waits on purpose
    (seccomp refuses both; this holds where there is no seccomp): its waiting is not counted.
    """
    out, own = {}, None
    for p in pids:
        try:
            with open(f"/proc/{p}/schedstat", "rb") as fh:
                waited = int(fh.read().split()[1]) / 1e9
        except (OSError, ValueError, IndexError):
            continue
        if own is None:
            own = _scheduling(os.getpid())
        its = _scheduling(p)
        if own is None or its is None or its[0] > own[0] or its[1] != own[1]:
            continue
        out[p] = waited
    return out


def run_delay(pids):
    """Seconds the processes ``pids`` have spent runnable but waiting for a processor (``/proc/<pid>/schedstat``,
    the kernel's scheduler accounting: no process can write it), or None when the kernel does not say."""
    got = _delays(pids)
    return sum(got.values()) if got else None


#: A wait of the grader's own (a select with a timeout) that returns more than this many seconds after the time it
#: asked for, or as long between two of its waits, was a pause of the grader: its process was stopped (SIGSTOP,
#: Ctrl-Z, ``docker pause``) or starved of a processor. The excess is time by which no one's code can be judged.
LATE = 0.5


class _Waiting:
    """The time processes spent waiting for a processor since this was made; ``pids()`` may name processes
    that started since (all their waiting counts) or have ended (theirs no longer does). With ``late``, the
    grader's own lateness measured by :func:`_select` counts too (both are no one's time).

    Both are leniency, and only where the sandbox cannot cause them: ``late`` is asked where seccomp is (no
    process of the sandbox can then signal the grader, nor change its own scheduling), and every stretch made
    of them is capped (``MAX_STRETCH``).
    """

    def __init__(self, pids, late=False):
        self.pids = pids
        self.base = _delays(pids())
        self.count_late = bool(late)
        self.late = 0.0  # seconds the grader itself was late (see lap)
        self._last = time.monotonic()

    def lap(self, asked=0.0):
        """The grader looks at the clock: the time since it last did, beyond the ``asked`` seconds of a wait it
        asked for, is the grader's lateness when over ``LATE`` (its own work between two looks takes milliseconds):
        its process was stopped or starved, wherever it was (in a wait, or before it could send a request)."""
        now = time.monotonic()
        over, self._last = now - self._last - asked, now
        if over > LATE and self.count_late:
            self.late += over

    def since(self):
        self.lap()
        now = _delays(self.pids())
        return self.late + sum(max(0.0, v - self.base.get(p, 0.0)) for p, v in now.items())


def _select(sel, timeout, *waitings):
    """``sel.select(timeout)``, the grader's lateness before and during it counted in each of ``waitings``."""
    timeout = max(0.0, timeout)
    waitings = [w for w in waitings if w is not None]
    for w in waitings:
        w.lap()
    events = sel.select(timeout=timeout)
    for w in waitings:
        w.lap(timeout)
    return events


class Sandbox:
    """One submission, loaded once in an isolated process that forks a worker per function.

    Parameters
    ----------
    units : list of dict
        The submission's code: ``{"source", "filename", "label"}`` per cell or file.
    functions : list of str
        Names the workers may call.
    limits : Limits
        Resource limits.
    display_name : str
        Name of the submission shown in messages.
    """

    #: Workers alive at once (the grader runs one per function, at most 7): as root with a fresh uid the zygote's
    #: ``RLIMIT_NPROC`` is one more; a fork it refuses is :class:`WorkerNotStarted`.
    max_workers = 8

    def __init__(self, units, functions, limits, display_name="submission"):
        self.units = units
        self.functions = list(functions)
        self.limits = limits
        self.display_name = display_name
        self.proc = None
        self.ready = None
        self.skip = []
        self.skip_notes = []
        self.cut = None  # (unit, statement): where the loading ran out of time; it and what follows are not run
        self._skipped_at = []  # (unit, statement, line) of the statements skipped
        self.load_timeout = limits.import_timeout  # what one loading (the probe's, a worker's) may take
        self.loads = 0
        self._ctl_link = None
        #: seconds of the loadings (all of them so far) that were no one's: their processes' waiting for a
        #: processor and the grader's own pauses, each loading's capped as its deadline's stretch
        self.waited = 0.0
        self._ctl = None
        self._out_r = None
        # guards the control socket and the process handle: a thread closing its worker (kill_worker) must never
        # use a socket another thread's kill() is closing, nor a descriptor number the next start has reused
        self._lock = threading.RLock()
        self._ids = itertools.count(1)
        # the workers' scratch folders start with it (/tmp/<prefix>-w1-...): without a mount namespace they are the
        # host's, and kill() removes them
        self._scratch_prefix = "ag" + os.urandom(8).hex()

    def _labels(self, unit, stmt, line):
        u = self.units[unit] if 0 <= unit < len(self.units) else {"label": "?"}
        return f"{u.get('label', '?')}, line {line}"

    # ------------------------------------------------------------------ lifecycle
    def start(self):
        """Spawn the sandbox and load the submission; return the ready message.

        A top-level statement that runs longer than ``limits.statement_timeout`` is
        skipped (the submission is loaded again without it), as an interrupted cell
        of a notebook would be; the whole loading may take ``limits.import_timeout``.
        When it runs out (or a 21st statement is over its deadline), the statement
        under way and every statement after it are left out, as in a kernel
        interrupted there, and the submission is loaded once more without them: the
        functions defined before are graded. That last loading, and each worker's
        from then on, may take twice ``limits.import_timeout`` (the statements kept
        took up to that time once; the margin is for a busy machine); it is done
        once per sandbox, and all of it counts in the submission's time budget but
        its waiting for a processor and the grader's pauses (``self.waited``).
        A loading whose process ended abruptly (killed, as by the kernel's
        out-of-memory killer) is tried once more.
        """
        lim = self.limits
        deadline = time.monotonic() + self.load_timeout
        killed = False
        while True:
            outcome = self._start_once(deadline)
            if outcome is None:
                return self.ready
            status, where = outcome
            if status == "eof" and not killed and time.monotonic() < deadline:
                # the loading process ended (an error of the submission's raises, and is skipped: an end this abrupt
                # is most often the machine's, an out-of-memory kill): once, the submission is loaded again; an end
                # the code itself causes comes back, and fails the loading then
                killed = True
                self.skip_notes.append(f"the process loading the submission ended ({where or status}) and the "
                                       "submission was loaded again")
                continue
            if status == "statement" and len(self.skip) < 20 and time.monotonic() < deadline:
                unit, stmt, line = where
                self.skip.append((unit, stmt))
                self._skipped_at.append((unit, stmt, line))
                self.skip_notes.append(f"{self._labels(unit, stmt, line)}: did not finish within "
                                       f"{lim.statement_timeout:g} s (statement skipped, as an interrupted cell)")
                continue
            # a statement under way, or one skipped earlier (the time may run out while a loading without it re-runs
            # the statements before it, which all ran once): the latest of them
            at = max(([tuple(where)] if status in ("timeout", "statement") and where is not None else [])
                     + self._skipped_at, default=None, key=lambda w: w[:2])
            if status in ("timeout", "statement") and at is not None and self.cut is None:
                # out of time (or of skips) during a statement: it and the rest of the top-level code are left out,
                # as in a kernel interrupted there, and the functions defined before it are graded
                unit, stmt, line = at
                self.cut = (unit, stmt)
                self.load_timeout = 2 * lim.import_timeout
                why = (f"loading the submission reached its {lim.import_timeout:g} s limit" if status == "timeout"
                       or time.monotonic() >= deadline else "more than 20 statements were over the statement limit")
                self.skip_notes.append(f"{self._labels(unit, stmt, line)}: {why}; this statement and every one after "
                                       "it were not run, as in an interrupted kernel (the functions defined before it "
                                       "are graded)")
                deadline = time.monotonic() + self.load_timeout
                continue
            out = self._zout_text
            self.kill()
            what = {
                "timeout": f"loading the submission took longer than {self.load_timeout:g} s (is there slow code at "
                           "the top level? put experiments under `if __name__ == \"__main__\":`)",
                "statement": f"loading the submission took longer than {self.load_timeout:g} s",
                "protocol": f"the process loading the submission sent a malformed message ({where})",
            }.get(status, f"the process loading the submission ended unexpectedly ({where or status})")
            raise ChildFailed(CallOutcome("timeout" if status == "timeout" else "crashed", error=what,
                                          output=out), reason=status)

    def _start_once(self, deadline):
        self.kill()
        lim = self.limits
        root = os.geteuid() == 0
        uid, gid = _child_ids() if root else (None, None)
        job = {
            "units": self.units,
            "functions": self.functions,
            "display_name": self.display_name,
            "sys_path": SITE_PATHS,
            "blocked_modules": list(BLOCKED_MODULES),
            "blocked_paths": BLOCKED_PATHS,
            "netns": lim.network,
            "fs": _fs(lim) if lim.filesystem else None,
            "uid": uid,
            "gid": gid,
            "audit": lim.audit,
            "block_processes": lim.block_processes,
            "seccomp": lim.seccomp,
            "skip": [list(s) for s in self.skip],
            "cut": list(self.cut) if self.cut is not None else None,
            "max_workers": self.max_workers,
            "scratch_prefix": self._scratch_prefix,
            "limits": {"cpu": lim.cpu, "as": lim.memory, "fsize": lim.file_size, "nproc": 0, "nofile": 256},
        }
        fill_standard_fds()  # the control socket and pipes never get the numbers 0-2
        parent_ctl, child_ctl = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        out_r, out_w = os.pipe()
        try:
            proc = subprocess.Popen(
                [sys.executable, "-I", "-S", RUNNER, str(child_ctl.fileno())],
                stdin=subprocess.PIPE, stdout=out_w, stderr=out_w, cwd="/", env=_env(),
                start_new_session=True, pass_fds=(child_ctl.fileno(),), close_fds=True)
        except BaseException:
            parent_ctl.close()
            os.close(out_r)
            raise
        finally:
            os.close(out_w)
            try:  # the sandbox's end of the control socket: its processes but the workers hold it (_own_pids)
                self._ctl_link = f"socket:[{os.fstat(child_ctl.fileno()).st_ino}]"
            except OSError:
                self._ctl_link = None
            child_ctl.close()
        with self._lock:  # published together: a reader sees the old sandbox's state or the new one's, never a mix
            self.proc = proc
            self.loads += 1
            self._ctl = parent_ctl
            self._out_r = out_r
        self._zout = bytearray()
        self._zout_total = 0
        try:
            proc.stdin.write(pack_frame(job))
            proc.stdin.close()
        except (BrokenPipeError, OSError):
            pass
        os.set_blocking(out_r, False)
        parent_ctl.setblocking(False)
        current = None  # (unit, stmt, line, started, the sandbox's waiting for a processor then)

        def tree():  # the loading processes (leniency only: see Worker.call), where seccomp is asked for
            return [proc.pid] + _descendants(proc.pid) if lim.seccomp else []

        def stretch(waiting, allowed):
            """Seconds the loading waited for a processor since ``waiting`` began, capped."""
            return min(waiting.since(), MAX_STRETCH * allowed)

        base, waited0 = deadline, _Waiting(tree, late=lim.seccomp)
        allowed = max(0.0, deadline - time.monotonic())
        sel = selectors.DefaultSelector()
        sel.register(parent_ctl, selectors.EVENT_READ, "ctl")
        sel.register(out_r, selectors.EVENT_READ, "out")
        looks, got_ctl = None, False  # once the time is up: the messages that arrived are read first (see below)
        try:
            while True:
                now = time.monotonic()
                over = None
                if now >= deadline:  # a loaded machine's waiting is no loading's time: the deadlines stretch by it
                    deadline = max(deadline, base + stretch(waited0, allowed))
                    if now >= deadline:
                        over = ("timeout", current[:3] if current is not None else None)
                limit = deadline
                if current is not None and over is None:
                    ends = current[3] + lim.statement_timeout
                    if now >= ends:
                        ends += stretch(current[4], lim.statement_timeout)
                    limit = min(limit, ends)
                    if now >= ends:
                        over = ("statement", current[:3])
                if over is None:
                    looks, wait = None, max(0.01, min(limit - now, 1.0))
                elif looks is None or (got_ctl and looks < 4096):
                    # before the time is called, what already arrived is read, without waiting (while messages
                    # come): a grader that was paused finds the loader's words of the meantime there (the next
                    # statement, the end) and judges by them, not by a clock that ran while it could not read
                    looks, wait = (looks or 0) + 1, 0.0
                else:
                    return over
                got_ctl = False
                for key, _ in _select(sel, wait, waited0, current[4] if current is not None else None):
                    if key.data == "out":
                        try:
                            chunk = os.read(out_r, 1 << 16)
                        except BlockingIOError:
                            continue
                        if not chunk:
                            sel.unregister(out_r)
                            continue
                        self._zout_total += len(chunk)
                        self._zout.extend(chunk)
                        if len(self._zout) > 8000:
                            del self._zout[:-4000]
                        # beyond the cap the output is read and dropped (the time limits bound how much): printing
                        # while loading is no error, and the functions are graded (a note says it was not kept)
                        continue
                    try:
                        data = parent_ctl.recv(1 << 20)
                    except BlockingIOError:
                        continue
                    except OSError:
                        data = b""
                    got_ctl = True
                    if not data:
                        code = None
                        try:
                            code = proc.wait(timeout=2)
                        except subprocess.TimeoutExpired:
                            pass
                        return ("eof", _exit_text(code))
                    try:
                        msg = control_message(data)  # untrusted: checked against its schema (autograder.wire)
                    except ProtocolError as exc:
                        return ("protocol", str(exc))
                    if msg.get("ev") == "stmt":
                        try:
                            at = (int(msg["unit"]), int(msg["stmt"]))
                        except (KeyError, TypeError, ValueError):
                            continue
                        # the loader runs each statement once, in order: an event for a statement that does not exist,
                        # or not after the last one, is the submission's (it would reset the statement's deadline)
                        if not self._statement_exists(at) or (current is not None and at <= current[:2]):
                            return ("protocol", f"a statement event out of order or for no statement {at}")
                        current = (*at, int(msg.get("line", 0)), time.monotonic(), _Waiting(tree, late=lim.seccomp))
                    elif msg.get("ev") == "ready":
                        printed = ([f"the top-level code printed {self._zout_total} bytes while loading; beyond "
                                    f"{lim.output} bytes its output was not kept"] if self._zout_total > lim.output
                                   else [])
                        msg["notes"] = (list(self.skip_notes) + printed
                                        + [str(n)[:300] for n in (msg.get("notes") or [])][:200])
                        self.ready = msg
                        return None
        finally:
            sel.close()
            # the loading's waiting for a processor and the grader's pauses, as they stretched its deadline: given
            # back to the budgets (autograder.engine), which ran during the loading; only where seccomp was in force
            # (asked for is not enough: the filter may have failed to install), as for the workers (_own_pids)
            held = bool(((self.ready or {}).get("isolation") or {}).get("seccomp"))
            self.waited += stretch(waited0, allowed) if held else 0.0

    def _statement_exists(self, at):
        """Whether ``(unit, statement)`` names a top-level statement of the submission (its count, when the units
        carry it: :func:`autograder.submission.load_submission` records it)."""
        unit, stmt = at
        if not 0 <= unit < len(self.units) or stmt < 0:
            return False
        count = self.units[unit].get("statements")
        return count is None or stmt < count

    @property
    def _zout_text(self):
        return clean_text(bytes(getattr(self, "_zout", b"")[-4000:]).decode("utf-8", "replace"))

    @property
    def alive(self):
        proc = self.proc  # one read: another thread may kill the sandbox meanwhile
        return proc is not None and proc.poll() is None

    def ended(self, timeout=0.0):
        """True when the sandbox process has ended, or ends within ``timeout`` seconds."""
        proc = self.proc
        if proc is None:
            return True
        if timeout <= 0:  # asked before every call: no exception raised and caught on the way
            return proc.poll() is not None
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            return False
        return True

    def kill(self):
        """Kill the sandbox and everything in it."""
        with self._lock:
            proc = self.proc
            if proc is not None:
                if proc.poll() is None:
                    try:
                        os.killpg(proc.pid, signal.SIGKILL)
                    except (ProcessLookupError, PermissionError):
                        pass
                    try:
                        proc.kill()
                    except ProcessLookupError:
                        pass
                try:
                    proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    pass
                try:
                    os.killpg(proc.pid, signal.SIGKILL)
                except (ProcessLookupError, PermissionError):
                    pass
                if proc.stdin:
                    try:
                        proc.stdin.close()
                    except OSError:
                        pass
            if self._ctl is not None:
                self._ctl.close()
                self._ctl = None
            if self._out_r is not None:
                try:
                    os.close(self._out_r)
                except OSError:
                    pass
                self._out_r = None
            if proc is not None:
                _remove_scratch(self._scratch_prefix)
            self.proc = None

    def close(self):
        """Stop the sandbox (politely first) and every worker."""
        with self._lock:
            if self.alive and self._ctl is not None:
                try:
                    self._ctl.setblocking(True)
                    self._ctl.send(b'{"op":"exit"}')
                    self.proc.wait(timeout=0.5)
                except (OSError, subprocess.TimeoutExpired):
                    pass
            self.kill()

    # ------------------------------------------------------------------ workers
    def fork_worker(self):
        """A fresh worker process forked from the loaded submission (a :class:`Worker`).

        Raises ChildFailed if the sandbox is gone (the caller may start it again).
        """
        with self._lock:
            if not self.alive or self._ctl is None:
                raise ChildFailed(CallOutcome("crashed", error="the sandbox process is not running"))
            req_r, req_w = os.pipe()
            res_r, res_w = os.pipe()
            out_r, out_w = os.pipe()
            wid = next(self._ids)
            try:
                self._ctl.setblocking(True)
                socket.send_fds(self._ctl, [json.dumps({"op": "fork", "id": wid}).encode()], [req_r, res_w, out_w])
            except OSError as exc:
                for f in (req_r, req_w, res_r, res_w, out_r, out_w):
                    os.close(f)
                raise ChildFailed(CallOutcome("crashed", error=f"the sandbox process is not running ({exc})")) from None
            finally:
                if self._ctl is not None:
                    self._ctl.setblocking(False)
            for f in (req_r, res_w, out_w):
                os.close(f)
            return Worker(self, wid, req_w, res_r, out_r)

    def kill_worker(self, wid):
        """Ask the sandbox to end worker ``wid`` (nothing to do when the sandbox is gone)."""
        with self._lock:
            if self._ctl is None:
                return
            try:
                self._ctl.setblocking(True)
                self._ctl.send(json.dumps({"op": "kill", "id": wid}).encode())
            except OSError:
                pass
            finally:
                try:
                    self._ctl.setblocking(False)
                except OSError:
                    pass


class Worker:
    """One worker process: calls of the submission's functions on its own pipes."""

    def __init__(self, sandbox, wid, req_w, res_r, out_r):
        self.sandbox = sandbox
        self.limits = sandbox.limits
        self.id = wid
        self._req_w, self._res_r, self._out_r = req_w, res_r, out_r
        for f in (req_w, res_r, out_r):
            os.set_blocking(f, False)
        self._res = bytearray()
        self._out = bytearray()
        self._out_total = 0
        self.dead = False
        self.loaded = False  # the worker's word that it has loaded the submission (its first frame) has come
        self.load_seconds = 0.0  # how long the grader waited for that word (no call's time)
        self.load_waited = 0.0  # of it, the no one's: the loading's waiting for a processor, the grader's pauses
        self.zygote_gone = False  # set when the result pipe closed without the zygote's word on the worker's end
        self.gone_before_call = False  # set when not a byte of the request could be written: the worker had ended
        self._pids = None  # the host process ids whose waiting for a processor is this worker's (see _own_pids)
        self._res_seen = False  # a byte has come on the result pipe (a pipe closed empty: the fork failed)

    def _seccomp(self):
        """Whether the sandbox holds seccomp: then, and only then, is the leniency for waiting given (_own_pids)."""
        return bool(((self.sandbox.ready or {}).get("isolation") or {}).get("seccomp"))

    def _own_pids(self):
        """The worker's host process id (the one process below the sandbox that reads this worker's request pipe,
        and not the control socket: the zygote holds both from the fork request until it has forked, and its
        waiting is not the worker's), else every process of the sandbox (their waiting then counts for each call:
        only ever more lenient).

        None without seccomp: a worker could then change its own scheduling (its priority, its processors)
        between two readings and wait on purpose; its waiting is given back only where it cannot.
        """
        if not self._seccomp():
            return []
        if self._pids is not None:
            return self._pids
        proc = self.sandbox.proc
        tree = _descendants(proc.pid) if proc is not None else []
        try:
            want = f"pipe:[{os.fstat(self._req_w).st_ino}]"
        except (OSError, TypeError):
            want = None
        ctl = getattr(self.sandbox, "_ctl_link", None)
        for p in tree if want else ():
            try:
                links = {os.readlink(f"/proc/{p}/fd/{fd}") for fd in os.listdir(f"/proc/{p}/fd")}
            except OSError:
                continue
            if want in links and (ctl is None or ctl not in links):
                self._pids = [p]
                return self._pids
        return ([proc.pid] if proc is not None else []) + tree  # not kept: the worker may not be forked yet

    def close(self, kill=True):
        if kill and not self.dead:
            self.sandbox.kill_worker(self.id)
        self.dead = True
        for f in ("_req_w", "_res_r", "_out_r"):
            fd = getattr(self, f, None)
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
                setattr(self, f, None)

    def call(self, fn, args, kwargs=None, *, timeout, names=(), global_seed=None):
        """Call ``fn(*args, **kwargs)`` in the worker; return a :class:`CallOutcome`."""
        kwargs = kwargs or {}
        if self.dead:
            return CallOutcome("crashed", error="the worker process is gone")
        header, payload = encode_args(args, kwargs, np)
        header.update({"op": "call", "fn": fn, "names": list(names)})
        if global_seed is not None:
            header["global_seed"] = int(global_seed)
        self._out = bytearray()
        self._out_total = 0
        if not self.loaded:
            failed = self._await_loaded()
            if failed is not None:
                return failed
        del self._res[:]  # bytes left over from an earlier call are no answer to this one
        waiting = _Waiting(self._own_pids, late=self._seccomp())
        deadline = time.monotonic() + timeout

        def stretched():
            # the call's deadline counts the worker's own time, not the time a loaded machine kept it waiting for a
            # processor (the kernel's accounting) nor the grader's own pauses, up to MAX_STRETCH times the limit more
            return deadline + min(waiting.since(), MAX_STRETCH * timeout)

        reply, rpayload, status, err = self._exchange(pack_frame(header, payload), deadline, stretched, waiting)
        waited = waiting.since()  # given back to the budgets (capped there over the grading)
        out = self._output_text()
        if reply is None:
            self.close()
            if status == "timeout":
                more = min(waited, MAX_STRETCH * timeout)
                extra = (f" (and {more:.1f} s more while the machine kept it waiting for a processor"
                         + (" or the grader was paused" if waiting.late else "") + ")" if more >= 0.1 else "")
                return CallOutcome("timeout", error=f"the call did not finish within {timeout:g} s{extra}", output=out,
                                   waited=waited)
            if status == "output":
                return CallOutcome("output", error=f"the function printed more than {self.limits.output} bytes",
                                   output=out)
            if status == "protocol":
                return CallOutcome("protocol", error=f"the grader could not read the function's result ({err})",
                                   output=out)
            return CallOutcome("crashed", error=f"the process running the function ended during the call ({err})",
                               output=out)
        try:
            # untrusted: schema, extents, byte cap; decoded by the call's deadline (stretched as the wait was)
            r = read_reply(reply, rpayload, np, deadline=deadline + min(waited, MAX_STRETCH * timeout) + 1.0)
            if r["status"] == "protocol":
                raise ProtocolError(r["error"][:200])
        except Exception as exc:  # anything a forged reply raises is a protocol error, never a result
            self.close()
            msg = str(exc) if isinstance(exc, ProtocolError) else type(exc).__name__
            return CallOutcome("protocol", error=f"the grader could not read the function's result ({msg})", output=out)
        if r["status"] == "error":
            return CallOutcome("error", error=r["error"], where=r["where"], mutated=r["mutated"], blocked=r["blocked"],
                               output=out, elapsed=r["elapsed"], waited=waited)
        return CallOutcome("ok", returned=r["returned"], mutated=r["mutated"], blocked=r["blocked"], output=out,
                           elapsed=r["elapsed"], waited=waited)

    def _await_loaded(self):
        """Wait (up to the sandbox's ``load_timeout``) for the worker's first frame, ``{"status": "loaded"}``.

        A worker loads the submission again after it is forked (its top-level code runs in every worker), and
        that time is no call's: the first call's deadline starts when the word has come. Returns None then,
        else the first call's outcome (the worker ended while loading, took too long, or sent something else).
        """
        t0 = time.monotonic()
        load_timeout = self.sandbox.load_timeout
        deadline = base = t0 + load_timeout
        waited0 = _Waiting(self._own_pids, late=self._seccomp())
        sel = selectors.DefaultSelector()
        looked = False  # once the time is up, the result pipe was read once more, without waiting
        try:
            sel.register(self._res_r, selectors.EVENT_READ, "res")
            sel.register(self._out_r, selectors.EVENT_READ, "out")
            while True:
                try:
                    got = parse_result_frame(self._res)
                except ProtocolError as exc:
                    status, err = "protocol", str(exc)
                    break
                if got is not None:
                    header, _, used = got
                    del self._res[:used]
                    if header == {"status": "loaded"}:
                        status, err = "ok", None
                    elif header.get("status") == "exited":  # written by the zygote: the worker ended while loading
                        self._drain_output()
                        status, err = "eof", str(header.get("exit"))[:100]
                    else:
                        status, err = "protocol", "a result arrived before the request was sent"
                    break
                left = deadline - time.monotonic()
                if left <= 0:  # as in call(): the time a loaded machine kept the loading waiting is no one's
                    deadline = max(deadline, base + min(waited0.since(), MAX_STRETCH * load_timeout))
                    left = deadline - time.monotonic()
                if left > 0:
                    looked = False
                elif looked:
                    status, err = "timeout", None
                    break
                if left <= 0:  # the word may be in the pipe already (the grader was paused): one look, no waiting
                    looked, left = True, 0.0
                res_closed = False
                for key, _ in _select(sel, min(left, 1.0), waited0):
                    if key.data == "res":
                        try:
                            chunk = os.read(self._res_r, 1 << 16)
                        except BlockingIOError:
                            continue
                        if not chunk:
                            res_closed = True
                        else:
                            self._res_seen = True
                            self._res.extend(chunk)
                            if len(self._res) > wire.MAX_PAYLOAD + wire.MAX_HEADER + 64:
                                res_closed = None
                    elif self._read_output() is False:
                        sel.unregister(self._out_r)
                if res_closed is None:
                    status, err = "protocol", "result too large"
                    break
                if res_closed and not self._res_seen and not self.sandbox.ended(timeout=2.0):
                    # closed with not a byte by a zygote that lives on: it could not fork the worker (a worker that
                    # ends is reported on this pipe, so no worker can close it empty)
                    status, err = "fork-failed", None
                    break
                if res_closed:  # the zygote holds this pipe too (it reports a worker's end on it): it is gone
                    self.zygote_gone = True
                    self._drain_output()
                    status, err = "eof", "the process ended"
                    break
        finally:
            sel.close()
            self.load_seconds = time.monotonic() - t0
            # no one's time (given back to the budgets, autograder.engine), capped as the deadline's stretch
            self.load_waited = min(waited0.since(), MAX_STRETCH * load_timeout)
        if status == "ok":
            self.loaded = True
            return None
        out = self._output_text()
        self.close()
        if status == "fork-failed":  # the machine's limits, not the submission: the grader's fault, never a score
            raise WorkerNotStarted("the sandbox could not start a process for the function: the machine's limit on "
                                   "processes (ulimit -u) or memory")
        if status == "timeout":
            return CallOutcome("timeout", output=out, error=(
                f"the process for this function did not finish loading the submission within "
                f"{load_timeout:g} s (every function's process runs the top-level code again: "
                "put experiments under `if __name__ == \"__main__\":`)"))
        if status == "eof":
            self.gone_before_call = True  # it ended before the call was sent: no call's doing
            return CallOutcome("crashed", output=out,
                               error=f"the process for this function ended while loading the submission ({err})")
        return CallOutcome("protocol", output=out, error=f"the grader could not read the function's result ({err})")

    def ended_between_calls(self):
        """True when the worker ended after its last call returned: its result pipe is closed, or bytes are waiting
        on it. A worker writes one frame per call, so bytes between calls are the zygote's word on its end (which
        may have come in the same read as the last answer) or a message nobody asked for; either way the worker is
        done. One non-blocking read: constant time, whatever a worker writes."""
        if self.dead:
            return True
        try:
            chunk = os.read(self._res_r, 1 << 16)
        except BlockingIOError:
            chunk = None
        except OSError:
            return True
        if chunk == b"":
            return True
        if chunk:
            self._res.extend(chunk)
        return bool(self._res)

    def _output_text(self):
        return clean_text(bytes(self._out[-4000:]).decode("utf-8", "replace"))

    def _exchange(self, request, deadline, stretched=None, waiting=None):
        """Write ``request``; read until one result frame arrives.

        Returns ``(header, payload, status, error)``; ``header`` is None when no
        frame arrived, and ``status`` says why: ``timeout``, ``output``, ``eof``
        (the worker died: its exit status comes from nowhere, so ``error`` says
        only that) or ``protocol``. ``stretched()`` is the deadline stretched by
        the time that was no one's (asked when the deadline has passed); the
        grader's own lateness is added to ``waiting`` (a :class:`_Waiting`).
        Before the time is called, the result pipe is read once more without
        waiting: a reply that arrived while the grader could not read (it was
        paused) is the answer.
        """
        pending = memoryview(request)
        sel = selectors.DefaultSelector()
        looked = False
        try:
            if pending:
                sel.register(self._req_w, selectors.EVENT_WRITE, "req")
            sel.register(self._res_r, selectors.EVENT_READ, "res")
            sel.register(self._out_r, selectors.EVENT_READ, "out")
            res_open = True
            while True:
                try:
                    got = parse_result_frame(self._res)
                except ProtocolError as exc:
                    return None, None, "protocol", str(exc)
                if got is not None:
                    header, payload, used = got
                    del self._res[:used]
                    if header.get("status") == "exited":  # written by the zygote when the worker ended
                        self._drain_output()
                        return None, None, "eof", str(header.get("exit"))[:100]
                    if pending:  # an answer to a request not yet read: forged ahead of time
                        return None, None, "protocol", "a result arrived before the request was sent"
                    return header, payload, "ok", None
                if not res_open:  # the zygote holds this pipe too (it reports its workers' ends): it is gone
                    self.zygote_gone = True
                    self._drain_output()
                    return None, None, "eof", "the process ended"
                left = deadline - time.monotonic()
                if left <= 0 and stretched is not None:
                    deadline = max(deadline, stretched())
                    left = deadline - time.monotonic()
                if left > 0:
                    looked = False
                elif looked:
                    return None, None, "timeout", None
                if left <= 0:
                    looked, left = True, 0.0
                    if not pending and res_open:  # the reply may be whole in the pipe already: read it all
                        res_open = self._drain_result()
                        if res_open is None:
                            return None, None, "protocol", "result too large"
                        continue
                for key, _ in _select(sel, min(left, 1.0), waiting):
                    if key.data == "req":
                        try:
                            n = os.write(self._req_w, pending)
                        except BlockingIOError:
                            continue
                        except (BrokenPipeError, OSError):
                            # only the worker reads this pipe: closed before the first byte, it had ended before
                            # the call
                            self.gone_before_call = self.gone_before_call or len(pending) == len(request)
                            sel.unregister(self._req_w)
                            pending = memoryview(b"")
                            continue
                        pending = pending[n:]
                        if not pending:
                            sel.unregister(self._req_w)
                    elif key.data == "res":
                        try:
                            chunk = os.read(self._res_r, 1 << 20)
                        except BlockingIOError:
                            continue
                        if not chunk:
                            sel.unregister(self._res_r)
                            res_open = False
                        else:
                            self._res.extend(chunk)
                            if len(self._res) > wire.MAX_PAYLOAD + wire.MAX_HEADER + 64:
                                return None, None, "protocol", "result too large"
                    else:
                        if self._read_output() is False:
                            sel.unregister(self._out_r)
                        if self._out_total > self.limits.output:
                            return None, None, "output", None
        finally:
            sel.close()

    def _drain_result(self):
        """Read what the result pipe holds now, without waiting: True while it is open, False at its end, None when
        more arrived than any result may hold."""
        while True:
            try:
                chunk = os.read(self._res_r, 1 << 20)
            except BlockingIOError:
                return True
            except OSError:
                return False
            if not chunk:
                return False
            self._res.extend(chunk)
            if len(self._res) > wire.MAX_PAYLOAD + wire.MAX_HEADER + 64:
                return None

    def _read_output(self):
        """Read what the worker printed; False at end of file, None when nothing is waiting."""
        try:
            chunk = os.read(self._out_r, 1 << 16)
        except BlockingIOError:
            return None
        except OSError:
            return False
        if not chunk:
            return False
        self._out_total += len(chunk)
        self._out.extend(chunk)
        if len(self._out) > 8000:
            del self._out[:-4000]
        return True

    def _drain_output(self):
        """What a dead worker printed last (its stderr names a fatal signal, for instance)."""
        for _ in range(64):
            if not self._read_output():
                return


# --------------------------------------------------------------------------- isolation report
_ISO_CACHE = {}
_ISO_LOCK = threading.Lock()


def isolation_report(limits=None):
    """Start one sandbox on an empty submission and return what isolation held.

    The answer is cached per process (it depends on the machine, not on the
    submission).
    """
    limits = limits or Limits()
    key = (limits.network, limits.audit, limits.filesystem, limits.seccomp)
    with _ISO_LOCK:
        if key not in _ISO_CACHE:
            box = Sandbox([{"source": "", "filename": "<probe>", "label": "probe"}], [], limits)
            try:
                ready = box.start()
                _ISO_CACHE[key] = dict(ready.get("isolation") or {})
            except ChildFailed as exc:
                _ISO_CACHE[key] = {"error": str(exc)}
            finally:
                box.close()
        return dict(_ISO_CACHE[key])


def protection_level(iso):
    """One word for the protection of the reference and the tests that was in force.

    ``"namespaces"`` (a minimal root without them), ``"separate-user"`` (another
    uid that cannot read them), or ``"audit-hook-only"`` (nothing but the hook: the
    files are readable by the submission's process).
    """
    if not iso or "error" in iso:
        return "unknown"
    if iso.get("fs"):
        return "namespaces"
    if not iso.get("reference_readable") and (iso.get("uid") not in (None, 0) or iso.get("root")):
        return "separate-user"
    return "audit-hook-only"


def describe_isolation(iso):
    """One line per isolation mechanism, from a sandbox's ``isolation`` report."""
    if not iso:
        return ["isolation: unknown (no sandbox started)"]
    if "error" in iso:
        return [f"isolation: the probe sandbox failed: {iso['error']}"]
    level = protection_level(iso)
    lines = [{"namespaces": "protection of the reference and tests: namespaces (a minimal root holding only Python, "
                            "NumPy, SciPy and the submission)",
              "separate-user": "protection of the reference and tests: a separate unprivileged user that cannot read "
                               "them (no mount namespace: " + str(iso.get("fs_error") or iso.get("mountns_error")
                                                                  or "unavailable") + ")",
              "audit-hook-only": "protection of the reference and tests: the audit hook ONLY (their files are readable "
                                 "by the submission's process: " + ", ".join(iso.get("reference_readable") or []) + ")",
              }[level]]
    lines.append("one sandbox per submission, loaded once; a fresh worker process per function (own pipes, wall-clock "
                 "deadline per call, output cap)")
    if iso.get("fs"):
        lines.append("files: private /tmp and /dev/shm (tmpfs, size-capped), fresh /proc, read-only system and Python "
                     "folders; nothing written reaches the host")
    else:
        lines.append("files: NOT isolated (" + str(iso.get("fs_error") or iso.get("mountns_error") or "no mount "
                                                                                                    "namespace") + ")")
    abi = iso.get("landlock_abi") or 0
    if abi >= 1:
        lines.append(f"scratch: each worker has its own /tmp and /dev/shm folders and sees no other (Landlock ABI {abi}"
                     + (": nor can it signal processes outside its domain" if abi >= 6 else "") + ")")
    else:
        lines.append("scratch: workers of one submission share /tmp and /dev/shm (no Landlock on this kernel)")
    if iso.get("pidns"):
        lines.append("processes: new PID namespace (the submission cannot see or signal processes outside it; "
                     "everything in it dies with it)")
        if iso.get("init"):
            lines.append("process 1: a minimal init that runs no submission code and cannot be signalled from inside; "
                         "it ends the namespace when the grader or its control socket goes away")
    else:
        lines.append("processes: NO PID namespace (" + str(iso.get("pidns_error", "unavailable")) + "): processes a "
                     "submission starts in its own session may outlive grading")
    if iso.get("seccomp"):
        lines.append(f"system calls: seccomp filter ({iso.get('seccomp_backend', '?')}) refuses keyrings, new "
                     "namespaces, ptrace, bpf, perf events, io_uring, mounts, other processes' memory, kernel modules, "
                     "SysV/POSIX IPC, sockets, memory files, extended attributes and grown pipes (memory no limit "
                     "counts), and changes of their own scheduling; workers may signal only themselves")
    else:
        lines.append("system calls: NO seccomp filter (" + str(iso.get("seccomp_error", "unavailable")) + ")")
    lines.append("kernel keyrings: " + ("a fresh session keyring per sandbox" if iso.get("session_keyring")
                                        else "the grader's session keyring (joining a fresh one failed)"))
    if iso.get("netns"):
        lines.append("network: new network namespace" + (" (inside a user namespace)" if iso.get("userns") else ""))
    else:
        lines.append("network: NOT isolated (" + str(iso.get("netns_error", "namespaces unavailable")) + ")")
    if iso.get("root"):
        if "uid_error" in iso:
            lines.append(f"privileges: root, and dropping them FAILED ({iso['uid_error']}): RLIMIT_NPROC does not apply")
        else:
            lines.append("privileges: dropped from root to a fresh unprivileged uid/gid per submission, drawn at random "
                         "and never repeated by this grader (RLIMIT_NPROC applies; submissions cannot signal each "
                         "other or the grader)")
    else:
        lines.append("privileges: runs as the grader's own (unprivileged) user"
                     + (", in a new user namespace without capabilities" if iso.get("userns") else ""))
    rl = iso.get("rlimits") or {}
    lines.append("rlimits: " + ", ".join(f"{k[7:]}={v}" for k, v in rl.items()))
    lines.append("audit hook (second line): " + ("imports of slamlib/autograder, their files, processes, sockets, "
                                                 "ctypes lookups refused" if iso.get("audit_hook") else "off"))
    return lines


# --------------------------------------------------------------------------- the grader's self-check
class WorkerNotStarted(RuntimeError):
    """The zygote could not fork a worker (``EAGAIN``, ``ENOMEM``): the machine's limits, never the submission's.

    Workers may start no process or thread (``RLIMIT_NPROC`` 0) and the zygote forks at most ``max_workers`` of them,
    so the submission cannot cause it. The zygote closes the worker's pipes without a byte (a worker cannot close its
    result pipe empty: the zygote holds it too and reports a worker's end on it); raised out of :meth:`Worker.call`,
    the grader's fault.
    """


class SandboxBroken(RuntimeError):
    """The sandbox cannot run a known-correct function on this machine: grading must not start."""


_PROBE_SOURCE = """
import numpy as np
import scipy
import scipy.linalg
import scipy.sparse
import scipy.special


def probe(a, b):
    factor = scipy.linalg.cho_factor(a)
    x = scipy.linalg.cho_solve(factor, b)
    y = scipy.sparse.csr_matrix(a) @ x
    return np.concatenate([x, y, [scipy.special.ndtr(0.0), scipy.special.erfc(0.0)]])
"""
_PROBE_A = np.array([[4.0, 1.0, 0.5], [1.0, 3.0, 0.25], [0.5, 0.25, 2.0]])
_PROBE_B = np.array([1.0, -2.0, 0.5])
_CHECKS = {}
_CHECK_LOCK = threading.Lock()


def _probe_expected():
    x = np.linalg.solve(_PROBE_A, _PROBE_B)
    return np.concatenate([x, _PROBE_A @ x, [0.5, 1.0]])


def failed_limits(isolation):
    """The resource limits the sandbox could not set (``"RLIMIT_AS: failed: ..."``), from its isolation report."""
    applied = (isolation or {}).get("rlimits") or {}
    return [f"{k}: {v}" for k, v in applied.items() if isinstance(v, str) and v.startswith("failed")]


def check_sandbox(limits=None, *, refresh=False):
    """Run one known-correct function in a sandbox, as a submission's would run; report what happened.

    The probe imports NumPy, SciPy and four SciPy subpackages at its top level
    (the grader's NumPy and SciPy, wherever they are installed: a virtual
    environment under ``/tmp``, ``~/.local``, ``/usr/local``, a conda prefix) and
    its function solves a small system with ``scipy.linalg``, multiplies with a
    ``scipy.sparse`` matrix and evaluates two special functions; the answer is compared
    with NumPy's in this process. The result is cached per process and set of
    limits.

    Returns
    -------
    dict
        ``ok`` (bool), ``problem`` (str or None: what failed), ``isolation``
        (the probe's isolation report), ``seconds``.
    """
    limits = limits or Limits()
    key = (limits.network, limits.filesystem, limits.audit, limits.seccomp, limits.tmp_size, limits.memory)
    with _CHECK_LOCK:
        if key in _CHECKS and not refresh:
            return dict(_CHECKS[key])
        t0 = time.monotonic()
        probe_limits = Limits(import_timeout=max(30.0, limits.import_timeout), statement_timeout=30.0,
                              memory=limits.memory, tmp_size=limits.tmp_size, network=limits.network,
                              filesystem=limits.filesystem, audit=limits.audit, seccomp=limits.seccomp)
        box = Sandbox([{"source": _PROBE_SOURCE, "filename": "<sandbox self-check>", "label": "sandbox self-check"}],
                      ["probe"], probe_limits, "sandbox self-check")
        problem, iso = None, {}
        try:
            ready = box.start()
            iso = dict(ready.get("isolation") or {})
            notes = [str(n) for n in ready.get("notes") or []]
            if notes:
                problem = "loading NumPy and SciPy in the sandbox failed: " + "; ".join(notes)[:1500]
            elif failed_limits(iso):
                problem = ("the sandbox could not set its resource limits (" + "; ".join(failed_limits(iso)) + "): the "
                           "grader was started with lower hard limits (ulimit -v / -t / -f / -n); a submission would be "
                           "held to them and lose points for the machine's limits. Start it without them.")
            elif not (ready.get("functions") or {}).get("probe", {}).get("defined"):
                problem = "the probe function was not defined in the sandbox"
            else:
                worker = box.fork_worker()
                try:
                    out = worker.call("probe", [_PROBE_A, _PROBE_B], timeout=30.0, names=("a", "b"))
                finally:
                    worker.close()
                if out.status != "ok":
                    problem = (f"the probe function's call ended with status {out.status!r}: {out.error} "
                               f"{out.where or ''} {out.output or ''}").strip()[:1500]
                else:
                    value = getattr(out.returned, "value", None)
                    got = getattr(value, "array", None)
                    want = _probe_expected()
                    if got is None or np.shape(got) != want.shape or not np.allclose(got, want, rtol=1e-9, atol=1e-12):
                        problem = f"the probe function returned {got!r} instead of {want!r}"
        except ChildFailed as exc:
            problem = f"the sandbox could not start or load the probe: {exc}"
            if exc.outcome.output:
                problem += f" (output: {exc.outcome.output[-1000:]})"
        except Exception as exc:  # noqa: BLE001 - whatever the machine refused (OSError, MemoryError under ulimit -v, a
            # worker it would not start): the check fails with it, it never ends the grader with a traceback
            problem = f"the sandbox could not start: {type(exc).__name__}" + (f": {exc}" if str(exc) else "")
            if isinstance(exc, MemoryError):
                problem += " (the grader's own memory: was it started under a low ulimit -v?)"
        finally:
            box.close()
        report = {"ok": problem is None, "problem": problem, "isolation": iso,
                  "seconds": round(time.monotonic() - t0, 3)}
        _CHECKS[key] = report
        return dict(report)


def require_sandbox(limits=None):
    """:func:`check_sandbox`, raising :class:`SandboxBroken` with a message for the course staff on failure."""
    report = check_sandbox(limits)
    if not report["ok"]:
        raise SandboxBroken(
            "The grader's sandbox cannot run a known-correct function on this machine, so grading stopped before "
            "any submission was graded (no results were written; nobody is charged).\n"
            f"What failed: {report['problem']}\n"
            f"Python: {sys.executable}; NumPy: {_package_dirs('numpy')[:1]}; SciPy: {_package_dirs('scipy')[:1]}\n"
            "Run `python -m autograder selfcheck` after fixing the installation.")
    return report
