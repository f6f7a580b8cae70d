"""Running untrusted submission code in a child process.

A :class:`Child` is one Python process (``python -I -S autograder/_runner.py``)
that loads the submission and then answers calls of one contract function. The
grader's process only sends arguments and reads back plain arrays; it never
imports or executes submission code.

What isolates a child (the runner applies the OS-level parts to itself before the
first line of submission code runs; see ``_runner.py``):

* a fresh process in its own session (process group), started in an empty
  scratch directory with a scrubbed environment and stdin closed;
* a wall-clock deadline per call, enforced here: on expiry the whole process
  group is killed with ``SIGKILL``;
* stdout and stderr read through one pipe with a byte cap (more output kills
  the child);
* results through a separate pipe, in a framed format of JSON and raw array
  bytes that this module validates (no pickles);
* resource limits (CPU seconds, 2 GiB of address space, file size, no new
  processes, no core dumps);
* when the grader runs as root: a unique unprivileged uid/gid per child (so
  ``RLIMIT_NPROC`` applies and one child cannot signal another); otherwise the
  caller's own uid inside a new user namespace;
* new network and PID namespaces where the kernel allows them (no interface but a
  down loopback; the submission is process 1 of its own PID namespace and cannot
  see or signal anything outside it);
* an audit hook refusing imports of ``slamlib``/``autograder``, reads of their
  files, new processes, sockets and ``ctypes`` symbol lookups.

:func:`isolation_report` describes what actually held on this machine.
"""

from __future__ import annotations

import itertools
import json
import os
import selectors
import signal
import site
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import _runner
from ._runner import ProtocolError, RngSeed, decode_result, encode_args, pack_frame, parse_frame

__all__ = ["Limits", "Child", "CallOutcome", "RngSeed", "isolation_report", "describe_isolation"]

RUNNER = str(Path(_runner.__file__).resolve())
_PKG_DIR = Path(__file__).resolve().parent
_counter = itertools.count()
_counter_lock = threading.Lock()


@dataclass(frozen=True)
class Limits:
    """Resource limits of one child process.

    Attributes
    ----------
    call_timeout : float or None
        Upper bound (seconds) on every call's wall time; a test's own timeout
        applies when smaller. ``None`` keeps the tests' timeouts.
    import_timeout : float
        Wall time allowed to load the submission (execute its top level).
    memory : int
        ``RLIMIT_AS`` in bytes.
    output : int
        Bytes of stdout+stderr a child may write before it is killed.
    file_size : int
        ``RLIMIT_FSIZE`` in bytes.
    cpu : int
        ``RLIMIT_CPU`` in seconds for the whole child (a backstop: calls are
        bounded by their wall-clock deadlines).
    network : bool
        Put the child in a new network namespace when possible.
    audit : bool
        Install the audit hook (imports, files, processes, sockets).
    block_processes : bool
        Let the audit hook refuse new processes (tests switch it off to check
        that the OS limits alone contain a fork).
    """

    call_timeout: float | None = None
    import_timeout: float = 30.0
    memory: int = 2 << 30
    output: int = 1 << 20
    file_size: int = 16 << 20
    cpu: int = 600
    network: bool = True
    audit: bool = True
    block_processes: bool = True


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


class ChildFailed(Exception):
    """The child could not be started or loaded (carries a CallOutcome)."""

    def __init__(self, outcome):
        super().__init__(outcome.error)
        self.outcome = outcome


def _site_paths():
    paths = []
    for mod in ("numpy", "scipy"):
        try:
            m = __import__(mod)
            paths.append(str(Path(m.__file__).resolve().parents[1]))
        except ImportError:
            pass
    try:
        paths.extend(site.getsitepackages())
    except AttributeError:
        pass
    out = []
    for p in paths:
        if p not in out and os.path.isdir(p):
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


SITE_PATHS = _site_paths()
BLOCKED_MODULES = ("slamlib", "autograder")
BLOCKED_PATHS = _blocked_paths()


def _child_ids():
    """A uid/gid no other running child uses (pid-derived, per-process counter)."""
    with _counter_lock:
        k = next(_counter) % 1000
    uid = 100000 + (os.getpid() % 4_000_000) * 1000 + k
    return uid, uid


def _env(scratch):
    return {
        "PATH": "/usr/bin:/bin",
        "HOME": scratch,
        "TMPDIR": scratch,
        "LANG": "C.UTF-8",
        "LC_ALL": "C.UTF-8",
        "MPLBACKEND": "Agg",
        "OMP_NUM_THREADS": "1",
        "OPENBLAS_NUM_THREADS": "1",
        "MKL_NUM_THREADS": "1",
        "NUMEXPR_NUM_THREADS": "1",
        "PYTHONHASHSEED": "0",
    }


class Child:
    """A child process serving calls of one function of a submission.

    Parameters
    ----------
    units : list of dict
        The submission's code: ``{"source", "filename", "label"}`` per cell or file.
    functions : list of str
        Names the child may call.
    limits : Limits
        Resource limits.
    display_name : str
        Name of the submission shown in messages.
    """

    def __init__(self, units, functions, limits, display_name="submission"):
        self.units = units
        self.functions = list(functions)
        self.limits = limits
        self.display_name = display_name
        self.proc = None
        self.ready = None
        self.scratch = None
        self._out = bytearray()
        self._res = bytearray()
        self._out_total = 0

    # ------------------------------------------------------------------ lifecycle
    def start(self):
        """Spawn the child and wait until it has loaded the submission."""
        self.close()
        self.scratch = tempfile.mkdtemp(prefix="slam-ag-")
        root = os.geteuid() == 0
        uid, gid = _child_ids() if root else (None, None)
        lim = self.limits
        job = {
            "units": self.units,
            "functions": self.functions,
            "display_name": self.display_name,
            "sys_path": SITE_PATHS,
            "blocked_modules": list(BLOCKED_MODULES),
            "blocked_paths": BLOCKED_PATHS,
            "netns": lim.network,
            "uid": uid,
            "gid": gid,
            "audit": lim.audit,
            "block_processes": lim.block_processes,
            "limits": {"cpu": lim.cpu, "as": lim.memory, "fsize": lim.file_size, "nproc": 0, "nofile": 256},
        }
        job_path = os.path.join(self.scratch, ".job.json")
        fd = os.open(job_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            json.dump(job, fh)
        if root:
            os.chown(self.scratch, uid, gid)
        os.chmod(self.scratch, 0o700)
        req_r, req_w = os.pipe()
        res_r, res_w = os.pipe()
        out_r, out_w = os.pipe()
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-I", "-S", RUNNER, job_path, str(req_r), str(res_w)],
                stdin=subprocess.DEVNULL, stdout=out_w, stderr=out_w, cwd=self.scratch, env=_env(self.scratch),
                start_new_session=True, pass_fds=(req_r, res_w), close_fds=True)
        finally:
            for f in (req_r, res_w, out_w):
                os.close(f)
        self._req_w, self._res_r, self._out_r = req_w, res_r, out_r
        for f in (req_w, res_r, out_r):
            os.set_blocking(f, False)
        self._out = bytearray()
        self._res = bytearray()
        self._out_total = 0
        header, _, status, err = self._exchange(b"", time.monotonic() + lim.import_timeout)
        if header is None or header.get("status") != "ready":
            out = self._output_text()
            self.kill()
            what = {
                "timeout": f"loading the submission took longer than {lim.import_timeout:g} s (is there slow code at "
                           "the top level? put experiments under `if __name__ == \"__main__\":`)",
                "output": f"the submission printed more than {lim.output} bytes while loading",
            }.get(status, f"the process loading the submission ended unexpectedly ({err or status})")
            raise ChildFailed(CallOutcome("crashed" if status not in ("timeout", "output") else status,
                                          error=what, output=out))
        self.ready = header
        return header

    def kill(self):
        proc = self.proc
        if proc is None:
            return
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
        # anything left in the group (it cannot fork, but be thorough)
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        for f in ("_req_w", "_res_r", "_out_r"):
            fd = getattr(self, f, None)
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
                setattr(self, f, None)
        self.proc = None

    def close(self):
        """Stop the child (politely if it is idle) and remove its scratch directory."""
        if self.proc is not None and self.proc.poll() is None and self._req_w is not None:
            try:
                os.set_blocking(self._req_w, True)
                os.write(self._req_w, pack_frame({"op": "exit"}))
            except OSError:
                pass
            try:
                self.proc.wait(timeout=0.5)
            except subprocess.TimeoutExpired:
                pass
        self.kill()
        if self.scratch:
            _rmtree(self.scratch)
            self.scratch = None

    # ------------------------------------------------------------------ calls
    def call(self, fn, args, kwargs=None, *, timeout, names=(), global_seed=None):
        """Call ``fn(*args, **kwargs)`` in the child; return a :class:`CallOutcome`."""
        kwargs = kwargs or {}
        if self.proc is None or self.proc.poll() is not None:
            self.start()
        header, payload = encode_args(args, kwargs, np)
        header.update({"op": "call", "fn": fn, "names": list(names)})
        if global_seed is not None:
            header["global_seed"] = int(global_seed)
        self._out = bytearray()
        reply, rpayload, status, err = self._exchange(pack_frame(header, payload), time.monotonic() + timeout)
        out = self._output_text()
        if reply is None:
            self.kill()
            if status == "timeout":
                return CallOutcome("timeout", error=f"the call did not finish within {timeout:g} s", output=out)
            if status == "output":
                return CallOutcome("output", error=f"the function printed more than {self.limits.output} bytes",
                                   output=out)
            if status == "protocol":
                return CallOutcome("protocol", error=f"the grader could not read the function's result ({err})",
                                   output=out)
            return CallOutcome("crashed", error=f"the process running the function ended during the call ({err})",
                               output=out)
        try:
            st = reply.get("status")
            if st not in ("ok", "error", "protocol"):
                raise ProtocolError(f"unexpected status {st!r}")
            mutated = [str(m)[:40] for m in reply.get("mutated") or []][:10]
            blocked = [str(b)[:200] for b in reply.get("blocked") or []][:20]
            elapsed = float(reply.get("elapsed") or 0.0)
            if st == "protocol":
                raise ProtocolError(str(reply.get("error"))[:200])
            if st == "error":
                return CallOutcome("error", error=str(reply.get("error"))[:2000], where=str(reply.get("where") or "")[:3000],
                                   mutated=mutated, blocked=blocked, output=out, elapsed=elapsed)
            returned = decode_result(reply.get("result"), rpayload, np)
        except (ProtocolError, TypeError, ValueError, AttributeError) as exc:
            self.kill()
            return CallOutcome("protocol", error=f"the grader could not read the function's result ({exc})", output=out)
        return CallOutcome("ok", returned=returned, mutated=mutated, blocked=blocked, output=out, elapsed=elapsed)

    # ------------------------------------------------------------------ plumbing
    def _output_text(self):
        return bytes(self._out[-4000:]).decode("utf-8", "replace")

    def _exchange(self, request, deadline):
        """Write ``request``; read until one result frame arrives.

        Returns ``(header, payload, status, error)``; ``header`` is None when no
        frame arrived, and ``status`` says why: ``timeout``, ``output``,
        ``eof`` or ``protocol``.
        """
        pending = memoryview(request)
        sel = selectors.DefaultSelector()
        try:
            if pending:
                sel.register(self._req_w, selectors.EVENT_WRITE, "req")
            sel.register(self._res_r, selectors.EVENT_READ, "res")
            sel.register(self._out_r, selectors.EVENT_READ, "out")
            res_open = True
            while True:
                try:
                    got = parse_frame(self._res)
                except ProtocolError as exc:
                    return None, None, "protocol", str(exc)
                if got is not None:
                    header, payload, used = got
                    del self._res[:used]
                    return header, payload, "ok", None
                if not res_open:
                    code = self.proc.poll() if self.proc else None
                    if code is None:
                        try:
                            code = self.proc.wait(timeout=1)
                        except subprocess.TimeoutExpired:
                            code = None
                    return None, None, "eof", _exit_text(code)
                left = deadline - time.monotonic()
                if left <= 0:
                    return None, None, "timeout", None
                for key, _ in sel.select(timeout=min(left, 1.0)):
                    if key.data == "req":
                        try:
                            n = os.write(self._req_w, pending)
                        except BlockingIOError:
                            continue
                        except (BrokenPipeError, OSError):
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
                            if len(self._res) > _runner.MAX_PAYLOAD + _runner.MAX_HEADER + 64:
                                return None, None, "protocol", "result too large"
                    else:
                        try:
                            chunk = os.read(self._out_r, 1 << 16)
                        except BlockingIOError:
                            continue
                        if not chunk:
                            sel.unregister(self._out_r)
                        else:
                            self._out_total += len(chunk)
                            self._out.extend(chunk)
                            if len(self._out) > 8000:
                                del self._out[:-4000]
                            if self._out_total > self.limits.output:
                                return None, None, "output", None
        finally:
            sel.close()


def _exit_text(code):
    if code is None:
        return "no exit status"
    if code < 0:
        try:
            return f"killed by signal {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit status {code}"


def _rmtree(path):
    import shutil

    shutil.rmtree(path, ignore_errors=True)


# --------------------------------------------------------------------------- isolation report
_ISO_CACHE = {}
_ISO_LOCK = threading.Lock()


def isolation_report(limits=None):
    """Start one child on an empty submission and return what isolation held.

    The answer is cached per process (it depends on the machine, not on the
    submission).
    """
    limits = limits or Limits()
    key = (limits.network, limits.audit)
    with _ISO_LOCK:
        if key not in _ISO_CACHE:
            child = Child([{"source": "", "filename": "<probe>", "label": "probe"}], [], limits)
            try:
                ready = child.start()
                _ISO_CACHE[key] = dict(ready.get("isolation") or {})
            except ChildFailed as exc:
                _ISO_CACHE[key] = {"error": str(exc)}
            finally:
                child.close()
        return dict(_ISO_CACHE[key])


def describe_isolation(iso):
    """One line per isolation mechanism, from a child's ``isolation`` report."""
    if not iso:
        return ["isolation: unknown (no child started)"]
    if "error" in iso:
        return [f"isolation: the probe child failed: {iso['error']}"]
    lines = ["separate process per function (own session, scratch directory, scrubbed environment, stdin closed, "
             "wall-clock deadline per call, output cap)"]
    if iso.get("pidns"):
        lines.append("processes: new PID namespace (the submission cannot see or signal processes outside it; "
                     "everything in it dies with it)")
    else:
        lines.append("processes: NO PID namespace (" + str(iso.get("pidns_error", "unavailable")) + ")")
    if iso.get("netns"):
        lines.append("network: new network namespace" + (" (inside a user namespace)" if iso.get("userns") else ""))
    else:
        lines.append("network: NOT isolated (" + str(iso.get("netns_error", "namespaces unavailable")) + ")")
    if iso.get("root"):
        if "uid_error" in iso:
            lines.append(f"privileges: root, and dropping them FAILED ({iso['uid_error']}): RLIMIT_NPROC does not apply")
        else:
            lines.append("privileges: dropped from root to a fresh unprivileged uid/gid per child (RLIMIT_NPROC applies; "
                         "children cannot signal each other or the grader)")
    else:
        lines.append("privileges: runs as the grader's own (unprivileged) user" + (", in a new user namespace" if iso.get("userns") else ""))
    rl = iso.get("rlimits") or {}
    lines.append("rlimits: " + ", ".join(f"{k[7:]}={v}" for k, v in rl.items()))
    lines.append("audit hook: " + ("imports of slamlib/autograder, their files, processes, sockets, ctypes lookups refused"
                                   if iso.get("audit_hook") else "off"))
    return lines
