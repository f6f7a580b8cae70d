"""The sandbox as an operating-system boundary.

* the grader checks its own sandbox before it grades, and a correct submission
  scores full marks wherever NumPy and SciPy are installed (a virtual environment
  under /tmp included);
* each worker has its own scratch space: nothing one function writes in /tmp or
  /dev/shm reaches another function's worker;
* process 1 of the sandbox runs no submission code, cannot be signalled from
  inside, and nothing a submission starts outlives a real ``grade`` process;
* a seccomp filter and a fresh session keyring: no kernel keyrings, no new user
  namespaces, and uids that are not derived from the grader's pid.
"""

from __future__ import annotations

import contextlib
import ctypes
import itertools
import json
import os
import secrets
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent / "autograder_fixtures"))

from agtest import by_function, replace_function, solution, solution_text  # noqa: E402

import autograder.engine as engine_mod  # noqa: E402
import autograder.sandbox as sandbox_mod  # noqa: E402
from autograder.engine import grade  # noqa: E402
from autograder.sandbox import Limits, Sandbox, isolation_report  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
TARGET, OTHER = "normalize_log_weights", "effective_sample_size"


@pytest.fixture(autouse=True)
def _secret(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("AUTOGRADER_SECRET_FILE", str(tmp_path_factory.getbasetemp() / "grading_secret"))


def _iso():
    return isolation_report(Limits())


def _require(*keys):
    iso = _iso()
    missing = [k for k in keys if not iso.get(k)]
    if missing:
        pytest.skip(f"this host does not provide {', '.join(missing)}")
    return iso


def _sandbox_output(source, functions, calls, limits=None):
    """Load ``source`` once; call each ``(function, args)`` in ``calls`` in its own fresh worker.

    Returns the printed output of each call (the probes print JSON) and the ready message.
    """
    box = Sandbox([{"source": source, "filename": "probe.py", "label": "probe"}], functions,
                  limits or Limits(call_timeout=10.0))
    outs = []
    try:
        ready = box.start()
        for fn, args in calls:
            w = box.fork_worker()
            try:
                o = w.call(fn, args, timeout=10.0)
            finally:
                w.close()
            outs.append(o)
    finally:
        box.close()
    return outs, ready


def _json_of(outcome):
    assert outcome.status == "ok", (outcome.status, outcome.error, outcome.where, outcome.output)
    return json.loads(outcome.output.strip().splitlines()[-1])


# =========================================================================== finding 1: an environment under /tmp
def _venv_under_tmp(where):
    """A virtual environment under ``where`` whose NumPy and SciPy live there (hard links: no copying when possible)."""
    venv = Path(where) / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    site = next((venv / "lib").glob("python3*/site-packages"))
    import numpy
    import scipy

    src = Path(numpy.__file__).resolve().parent.parent
    for name in ("numpy", "scipy", "numpy.libs", "scipy.libs"):
        s = Path(numpy.__file__ if name.startswith("numpy") else scipy.__file__).resolve().parent.parent / name
        if not s.exists():
            continue
        if subprocess.run(["cp", "-al", str(s), str(site / name)], capture_output=True).returncode != 0:
            shutil.rmtree(site / name, ignore_errors=True)
            shutil.copytree(s, site / name, symlinks=True)
    # the grader itself and its other dependencies from the test's environment, after NumPy and SciPy
    (site / "zz_grader.pth").write_text(f"{ROOT}\n{src}\n")
    py = venv / "bin" / "python"
    where_np = subprocess.run([str(py), "-c", "import numpy, scipy; print(numpy.__file__); print(scipy.__file__)"],
                              capture_output=True, text=True, check=True).stdout.split()
    assert all(p.startswith(str(Path(where).resolve())) for p in where_np), where_np
    return py


@pytest.fixture(scope="module")
def tmp_venv():
    base = Path(tempfile.mkdtemp(prefix="ag-venv-", dir="/tmp" if os.path.isdir("/tmp") else None))
    try:
        yield _venv_under_tmp(base)
    finally:
        shutil.rmtree(base, ignore_errors=True)


def test_correct_submission_scores_full_marks_from_an_environment_under_tmp(tmp_venv, tmp_path):
    """NumPy and SciPy of a venv under /tmp are visible in the sandbox (its private /tmp used to hide them)."""
    res = tmp_path / "results.json"
    p = subprocess.run([str(tmp_venv), "-m", "autograder", "grade", str(solution("motion_sensor_models")),
                        "-e", "motion_sensor_models", "--results", str(res)],
                       capture_output=True, text=True, cwd=str(ROOT), timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    data = json.loads(res.read_text())
    failed = [t["name"] for t in data["tests"] if t["score"] != t["max_score"]]
    assert data["score"] == 100.0 and not failed, (failed, p.stdout[-3000:])


@pytest.mark.parametrize("command", ["grade", "batch", "gradescope"])
def test_a_grader_that_cannot_import_scipy_stops_before_charging_anyone(tmp_path, command, monkeypatch, capsys):
    from autograder.__main__ import main

    iso = _iso()
    if not iso.get("fs"):
        pytest.skip("no minimal root on this host: the sandbox sees the grader's own site-packages")
    spec = dict(sandbox_mod.fs_spec(Limits()))
    spec["allow"] = [p for p in spec["allow"] if "scipy" not in p]  # SciPy invisible in the sandbox
    monkeypatch.setattr(sandbox_mod, "_fs", lambda limits: spec)
    monkeypatch.setattr(sandbox_mod, "_CHECKS", {})
    sub = tmp_path / "subs" / "alice"
    sub.mkdir(parents=True)
    shutil.copy(solution("motion_sensor_models"), sub / "01_motion_sensor_models.py")
    res = tmp_path / "results.json"
    if command == "grade":
        args = ["grade", str(sub / "01_motion_sensor_models.py"), "-e", "motion_sensor_models", "--results", str(res)]
    elif command == "batch":
        args = ["batch", str(tmp_path / "subs"), "-e", "motion_sensor_models", "--out", str(tmp_path / "g.csv"),
                "--results-dir", str(tmp_path / "rdir"), "--quiet"]
    else:
        (tmp_path / "submission").mkdir()
        shutil.copy(solution("motion_sensor_models"), tmp_path / "submission" / "01_motion_sensor_models.py")
        args = ["gradescope", "--root", str(tmp_path), "-e", "motion_sensor_models"]
        res = tmp_path / "results" / "results.json"
    rc = main(args)
    err = capsys.readouterr().err
    assert rc == 3, (rc, err)
    assert "No module named 'scipy'" in err and "nobody is charged" in err, err
    assert not res.exists() and not (tmp_path / "g.csv").exists()
    assert not (tmp_path / "rdir").exists() or not any((tmp_path / "rdir").glob("*.json"))


def test_selfcheck_reports_the_protections():
    from autograder.__main__ import main

    assert main(["selfcheck"]) == 0


# =========================================================================== finding 4: scratch space per worker
SCRATCH = r'''
import json, os, tempfile

def write(tag):
    out = {}
    for d in ("/tmp", "/dev/shm", tempfile.gettempdir(), os.getcwd()):
        p = os.path.join(d, "secret-" + str(tag))
        try:
            with open(p, "w") as fh:
                fh.write("ANSWER")
            out[p] = "written"
        except OSError as exc:
            out[p] = type(exc).__name__
    print(json.dumps(out))
    return 0.0

def look(tag, paths):
    found = []
    for top in ("/tmp", "/dev/shm", "/proc"):
        for root, dirs, files in os.walk(top, onerror=lambda e: None):
            if top == "/proc":
                dirs[:] = [d for d in dirs if d.isdigit() or d == "self"] if root == "/proc" else []
                files = [f for f in files if f in ("comm", "cmdline")]
            for f in files:
                p = os.path.join(root, f)
                try:
                    with open(p, "rb") as fh:
                        if b"ANSWER" in fh.read(1 << 16):
                            found.append(p)
                except OSError:
                    pass
    for p in bytes(paths.astype("uint8")).decode().split("\n"):  # exactly where the writer wrote
        try:
            with open(p) as fh:
                found.append(p + ":" + fh.read())
        except OSError:
            pass
    print(json.dumps({"found": found, "tmp": tempfile.gettempdir()}))
    return 0.0

def mark_name(tag):
    import ctypes
    ctypes.CDLL(None).prctl(15, b"ANSWER", 0, 0, 0)   # PR_SET_NAME: /proc/<pid>/comm
    return 0.0
'''


def test_one_functions_files_never_reach_another_functions_worker():
    """Files in /tmp and /dev/shm (and the worker's temp folder and cwd) stay with the worker that wrote them."""
    box = Sandbox([{"source": SCRATCH, "filename": "probe.py", "label": "probe"}], ["write", "look", "mark_name"],
                  Limits(call_timeout=10.0, audit=False))
    try:
        box.start()
        writer = box.fork_worker()  # alive while the others look: concurrent workers
        wrote = _json_of(writer.call("write", [1.0], timeout=10.0))
        assert "written" in wrote.values(), wrote
        namer = box.fork_worker()
        assert namer.call("mark_name", [0.0], timeout=10.0).status == "ok"
        paths = np.frombuffer("\n".join(p for p, v in wrote.items() if v == "written").encode(), dtype=np.uint8)
        looker = box.fork_worker()
        seen = _json_of(looker.call("look", [1.0, paths.astype(float)], timeout=10.0))
        looker.close()
        writer.close()
        later = box.fork_worker()  # and after the writer is gone
        seen_later = _json_of(later.call("look", [1.0, paths.astype(float)], timeout=10.0))
        later.close()
        namer.close()
    finally:
        box.close()
    assert seen["found"] == [] and seen_later["found"] == [], (wrote, seen, seen_later)


# =========================================================================== finding 5: process 1, signals, survivors
def _marked(marker):
    """Host pids whose comm, cmdline or environ carry ``marker``."""
    out = []
    m = marker.encode()
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        for f in ("comm", "cmdline", "environ"):
            try:
                if m in (d / f).read_bytes():
                    out.append(int(d.name))
                    break
            except OSError:
                continue
    return out


ESCAPE = r'''
import ctypes, os, signal, sys, time

MARK = {marker!r}
_NR = {{"x86_64": (56, 112), "aarch64": (220, 157)}}.get(os.uname().machine, (56, 112))


def _handles():
    """ctypes handles the grader's runner already resolved (the audit hook refuses new lookups)."""
    main = sys.modules.get("__main__")
    out = []
    for name in dir(main):
        v = getattr(main, name, None)
        for c in (v if isinstance(v, list) else [v]):
            if isinstance(c, ctypes.CDLL) and "syscall" in c.__dict__ and "prctl" in c.__dict__:
                out.append(c)
    try:
        lib = ctypes.CDLL(None)
        out.append(lib)
    except Exception:
        pass
    return out


def _stay():
    for lib in _handles():
        try:
            lib.prctl(1, 0, 0, 0, 0)  # clear the parent-death signal
            lib.prctl(15, MARK[:15].encode(), 0, 0, 0)  # a name the test finds in /proc/<pid>/comm
            lib.syscall(_NR[1])  # setsid()
            break
        except Exception:
            continue
    for s in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
        try:
            signal.signal(s, signal.SIG_IGN)
        except Exception:
            pass
    os._exit = lambda *a: None


def _fork():
    try:
        import resource
        soft, hard = resource.getrlimit(resource.RLIMIT_NPROC)
        resource.setrlimit(resource.RLIMIT_NPROC, (hard, hard))
    except Exception:
        pass
    for lib in _handles():
        try:
            return lib.syscall(_NR[0], 17, 0, 0, 0, 0)  # clone(SIGCHLD): a raw fork
        except Exception:
            continue
    return -1


def escape():
    pid = _fork()
    if pid == 0:
        _stay()
        if _fork() == 0:  # double fork: the grandchild is nobody's child
            _stay()
        while True:
            time.sleep(0.2)
    return pid


_stay_parent = escape()
_stay()  # the loading process too: no parent-death signal, its own session, SIGTERM ignored, os._exit a no-op


def _linger():
    while True:
        time.sleep(0.2)


import threading
threading.Thread(target=_linger).start()  # a non-daemon thread: the interpreter never finishes on its own
'''


def _escape_submission(tmp_path, marker):
    text = solution_text("particle_filter")
    body = ("def normalize_log_weights(log_w):\n    escape()\n    m = np.max(log_w)\n"
            "    w = np.exp(log_w - m)\n    return w / w.sum()\n")
    text = replace_function(text, TARGET, body)
    path = tmp_path / "escape.py"
    path.write_text("import numpy as np\n" + ESCAPE.format(marker=marker) + "\n" + text)
    return path


@pytest.mark.parametrize("how", ["exit", "sigkill"])
def test_nothing_a_submission_starts_outlives_a_real_grade_process(tmp_path, how):
    """Cleared parent-death signal, setsid(), double fork, os._exit replaced, SIGTERM ignored: all gone afterwards."""
    if not _iso().get("pidns"):
        pytest.skip("no PID namespace on this host")
    marker = "agx" + secrets.token_hex(6)
    path = _escape_submission(tmp_path, marker)
    proc = subprocess.Popen([sys.executable, "-m", "autograder", "grade", str(path), "-e", "particle_filter",
                             "--results", str(tmp_path / "r.json"), "--timeout", "5"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=str(ROOT), start_new_session=True)
    seen = False
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            if _marked(marker):
                seen = True
                if how == "sigkill":
                    proc.kill()  # the grader dies abruptly, mid-grading
                    break
            time.sleep(0.05)
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert seen, "the submission's escape never started a process (the test would prove nothing)"
    deadline = time.monotonic() + 5
    while _marked(marker) and time.monotonic() < deadline:
        time.sleep(0.1)
    alive = _marked(marker)
    for pid in alive:  # do not leave them running on the test machine
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass
    assert alive == [], f"processes of the submission outlived the grader: {alive}"
    if how == "exit":
        assert proc.returncode == 0, err.decode()[-2000:]
        data = json.loads((tmp_path / "r.json").read_text())
        assert data["tests"]


def _attack(tmp_path, body, limits):
    text = replace_function(solution_text("particle_filter"), TARGET, body)
    path = tmp_path / "attack.py"
    path.write_text("import os\nimport numpy as np\n" + text)
    result = grade(path, "particle_filter", limits=limits, functions=[TARGET, OTHER], workers=2)
    scores = result.by_function()
    out = "\n".join(t.output for t in result.tests if t.function == TARGET)
    return scores, out, result


SIGNAL_PARENTS = """def normalize_log_weights(log_w):
    import signal, time
    for _ in range(3):
        for target in (1, os.getppid()):
            for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
                try:
                    os.kill(target, sig)
                except OSError:
                    pass
        time.sleep(0.05)
    m = np.max(log_w)
    w = np.exp(log_w - m)
    return w / w.sum()
"""


@pytest.mark.parametrize("audit, backend", [(False, True), (False, "bpf"), (True, True)])
def test_signalling_process_1_or_the_zygote_costs_only_that_function(tmp_path, audit, backend):
    lim = Limits(call_timeout=2.5, audit=audit, block_processes=audit)
    if backend != lim.seccomp:
        lim = Limits(call_timeout=2.5, audit=audit, block_processes=audit, seccomp=backend)
    scores, out, result = _attack(tmp_path, SIGNAL_PARENTS, lim)
    assert scores[OTHER] == (15.0, 15.0), result.text_report()
    # the signals were refused: the function itself ran to the end and is judged on its (correct) values
    assert scores[TARGET][0] == scores[TARGET][1], result.text_report()


HIJACK = """import json, os, sys
def who():
    print(json.dumps({"pid": os.getpid()}))
    return 1.0
def _hijack():
    # the probe that loads the submission for the grader: keep its control socket, say ready, never finish loading
    f = sys._getframe()
    while f is not None and f.f_code.co_name != "_probe":
        f = f.f_back
    if f is None:  # a worker loads the submission too: nothing to take there
        return
    g, loc = f.f_globals, f.f_locals
    g["_send_ready"](loc["ctl"], loc["job"], sys.modules["submission"], [], loc["attempts"], {})
    import time
    while True:
        time.sleep(1)
_hijack()
"""


def test_the_process_that_loads_the_submission_for_the_grader_cannot_take_the_forks():
    """The probe's code says ready on its own and stays: it is ended before any fork, and every call runs in a
    worker of its own (the probe once held the socket fork requests came on, and one process served them all)."""
    lim = Limits(call_timeout=5.0, import_timeout=15.0)
    outs, ready = _sandbox_output(HIJACK, ["who"], [("who", []), ("who", [])], lim)
    pids = [_json_of(o)["pid"] for o in outs]  # each call answered, each by a worker of its own
    assert pids[0] != pids[1], pids


def test_a_signature_too_long_for_one_message_does_not_fail_the_loading():
    """A contract function with a large default argument (a table of 60 000 numbers) made the ready message 400 kB,
    more than one datagram holds: the loading looked like a crash, and correct code scored 0."""
    src = "def who(w=None, _table=tuple(range(60000))):\n    return 1.0\n"
    outs, ready = _sandbox_output(src, ["who"], [("who", [])], Limits(call_timeout=5.0))
    assert outs[0].status == "ok" and len(ready["functions"]["who"]["signature"]) <= 1000, ready["functions"]


def test_slow_top_level_code_is_no_function_s_time(tmp_path):
    """Every worker runs the top-level code again after it is forked: that time must not count against the first
    call's deadline (statements of 1.5 s, a call limit of 1 s: correct code once scored 0)."""
    text = solution_text("particle_filter") + "\nimport time\nfor _ in range(2):\n    time.sleep(0.75)\n"
    path = tmp_path / "experiments.py"
    path.write_text(text)
    lim = Limits(call_timeout=1.0, statement_timeout=5.0, import_timeout=20.0)
    result = grade(path, "particle_filter", limits=lim, functions=[OTHER])
    got, top = result.by_function()[OTHER]
    assert got == top > 0, result.text_report()


FORGED_ISOLATION = HIJACK.replace('loc["attempts"], {})', 'loc["attempts"], {"FORGED": True, "seccomp": True})')


def test_which_protections_held_is_never_the_submission_s_word():
    """The probe runs submission code, which can send its own ready message: the isolation report in it is replaced
    by the sandbox's own before the grader reads it."""
    assert FORGED_ISOLATION != HIJACK
    _, ready = _sandbox_output(FORGED_ISOLATION, ["who"], [], Limits(call_timeout=5.0, import_timeout=15.0))
    iso = ready["isolation"]
    assert "FORGED" not in iso and "audit_hook" in iso, iso  # the sandbox's own report, whole


def test_process_1_runs_no_submission_code():
    iso = _require("pidns", "init")
    src = ("import os, json\ndef who():\n"
           "    print(json.dumps({'pid': os.getpid(), 'ppid': os.getppid(), 'zygote': ZYGOTE}))\n    return 0.0\n"
           "ZYGOTE = os.getpid()\n")
    (o,), ready = _sandbox_output(src, ["who"], [("who", [])])
    got = _json_of(o)
    # top-level code runs in the worker itself (forked from a zygote that never runs submission code)
    assert iso["init"] and got["zygote"] == got["pid"] != 1 and got["ppid"] not in (1, got["pid"]), got


# =========================================================================== finding 7: keyrings, namespaces, uids
KEYS = r'''
import ctypes, json, os
libc = ctypes.CDLL(None, use_errno=True)
NR = {{"x86_64": dict(add_key=248, request_key=249, keyctl=250, unshare=272, setns=308, ptrace=101, bpf=321,
                     perf_event_open=298, io_uring_setup=425, mount=165, userfaultfd=323, memfd_create=319,
                     setxattr=188),
      "aarch64": dict(add_key=217, request_key=218, keyctl=219, unshare=97, setns=268, ptrace=117, bpf=280,
                      perf_event_open=241, io_uring_setup=425, mount=40, userfaultfd=282, memfd_create=279,
                      setxattr=5)}}[os.uname().machine]
GRADER_KEY = {grader_key}
PROBE_KERNEL = {kernel}

def call(name, *args):
    r = libc.syscall(NR[name], *args)
    return [r, ctypes.get_errno() if r < 0 else 0]

def keys(store):
    print(json.dumps(_keys(store)))
    return 0.0

def probe(store):
    out = _keys(store)
    out.update(_kernel())
    print(json.dumps(out))
    return 0.0

def _keys(store):
    out = {{}}
    buf = ctypes.create_string_buffer(256)
    out["read_grader_key"] = call("keyctl", 11, GRADER_KEY, buf, 256)  # KEYCTL_READ
    out["search_session"] = call("keyctl", 10, -3, b"user", b"ag-boundary-key", 0)  # KEYCTL_SEARCH
    out["search_user"] = call("keyctl", 10, -4, b"user", b"ag-boundary-mine", 0)
    if store:
        out["add_user_key"] = call("add_key", b"user", b"ag-boundary-mine", b"stored", 6, -4)
    out["request_key"] = call("request_key", b"user", b"ag-boundary-key", None, 0)
    return out

def _kernel():
    out = {{}}
    out["unshare_user"] = call("unshare", 0x10000000)
    out["unshare_mnt"] = call("unshare", 0x00020000)
    out["setns"] = call("setns", 0, 0)
    out["ptrace"] = call("ptrace", 16, 1, 0, 0)  # PTRACE_ATTACH to process 1
    out["bpf"] = call("bpf", 0, None, 0)
    out["perf_event_open"] = call("perf_event_open", None, 0, -1, -1, 0)
    out["io_uring_setup"] = call("io_uring_setup", 1, None)
    out["mount"] = call("mount", b"none", b"/tmp", b"tmpfs", 0, None)
    out["userfaultfd"] = call("userfaultfd", 0)
    # memory outside RLIMIT_AS and the sandbox's tmpfs caps: anonymous memory files, pipes grown (F_SETPIPE_SZ)
    out["memfd_create"] = call("memfd_create", b"held", 0)
    r, w = os.pipe()
    grown = libc.fcntl(w, 1031, 1 << 20)
    out["pipe_grown"] = [grown, ctypes.get_errno() if grown < 0 else 0]
    import tempfile
    fd, name = tempfile.mkstemp()
    out["setxattr"] = call("setxattr", name.encode(), b"user.held", b"x" * 4096, 4096, 0)  # kernel memory per file
    out["at_load_search"], out["at_load_unshare_user"] = AT_LOAD[:2], AT_LOAD[2:]
    return out

AT_LOAD = call("keyctl", 10, -3, b"user", b"ag-boundary-key", 0) + (call("unshare", 0x10000000) if PROBE_KERNEL else [])
'''


def _host_has_seccomp():
    try:
        return "Seccomp:" in Path("/proc/self/status").read_text()
    except OSError:
        return False


def _grader_session_key():
    """A key in this (the grader's) session keyring, as a deployment's credentials could be."""
    libc = ctypes.CDLL(None, use_errno=True)
    nr = {"x86_64": 248, "aarch64": 217}.get(os.uname().machine)
    if nr is None:
        pytest.skip("unknown architecture")
    kid = libc.syscall(nr, b"user", b"ag-boundary-key", b"grader-secret", 13, ctypes.c_long(-3))
    if kid < 0:
        pytest.skip(f"cannot add a key to the session keyring here: {os.strerror(ctypes.get_errno())}")
    return kid


@pytest.mark.parametrize("backend", [True, "bpf"])
def test_no_kernel_keyrings_no_namespaces_no_tracing(backend):
    """keyctl, add_key, request_key, unshare(CLONE_NEWUSER), setns, ptrace, bpf, perf, io_uring, mount all refused.

    Through libseccomp, and through the BPF program the runner builds where libseccomp is not installed.
    """
    if not _host_has_seccomp():
        pytest.skip("the kernel has no seccomp filters")
    lim = Limits(call_timeout=10.0, audit=False, **({} if backend is True else {"seccomp": backend}))
    kid = _grader_session_key()
    src = KEYS.format(grader_key=kid, kernel=True)
    (o,), ready = _sandbox_output(src, ["probe"], [("probe", [1.0])], lim)
    got = _json_of(o)
    for name, (ret, err) in got.items():
        assert ret < 0 and err in (1, 38), (name, got)  # EPERM (ENOSYS for clone3-like cases)
    iso = ready["isolation"]
    assert iso.get("seccomp") and iso.get("session_keyring"), iso
    assert iso["seccomp_backend"] == ("bpf" if backend == "bpf" else iso["seccomp_backend"])


def test_grader_keys_and_earlier_submissions_keys_are_out_of_reach_without_the_filter():
    """The fresh session keyring and the uid pool hold on their own (seccomp off): nothing to read or replay."""
    lim = Limits(call_timeout=10.0, audit=False)
    if "seccomp" in Limits.__dataclass_fields__:
        lim = Limits(call_timeout=10.0, audit=False, seccomp=False)
    iso = isolation_report(lim)
    if not iso.get("root") or "uid_error" in iso:
        pytest.skip("needs root: without a separate uid the grader's user keyring is the sandbox's")
    kid = _grader_session_key()
    src = KEYS.format(grader_key=kid, kernel=False)
    (first,), _ = _sandbox_output(src, ["keys"], [("keys", [1.0])], lim)
    a = _json_of(first)
    assert a["add_user_key"][0] > 0, a  # the filter is off: storing works
    (second,), _ = _sandbox_output(src, ["keys"], [("keys", [0.0])], lim)
    b = _json_of(second)
    for got in (a, b):
        assert got["read_grader_key"][0] < 0 and got["search_session"][0] < 0 and got["request_key"][0] < 0, got
    assert b["search_user"][0] < 0, b  # the next submission has another uid, so another user keyring


def test_uids_come_from_a_pool_not_from_the_graders_pid(monkeypatch):
    """Two grader processes that happen to share a pid (pids are reused) still hand out different uids."""
    firsts = []
    for _ in range(2):  # two "processes": same pid, fresh per-process state
        monkeypatch.setattr(sandbox_mod.os, "getpid", lambda: 4242)
        monkeypatch.setattr(sandbox_mod, "_counter", itertools.count())
        if hasattr(sandbox_mod, "_USED_IDS"):
            monkeypatch.setattr(sandbox_mod, "_USED_IDS", set())
        firsts.append(sandbox_mod._child_ids())
    assert firsts[0] != firsts[1]
    many = [sandbox_mod._child_ids()[0] for _ in range(500)]
    assert len(set(many)) == len(many)
    assert all(1000 < u < 2**31 - 1 and u != 65534 for u in many)


# =========================================================================== a worker against the zygote, forged frames
FIXTURES = Path(__file__).resolve().parent / "autograder_fixtures"


def test_a_worker_cannot_have_the_kernel_kill_the_zygote_and_other_functions_keep_their_marks():
    """Signal-driven I/O (F_SETOWN + F_SETSIG(SIGKILL) + O_ASYNC) aimed at the zygote is refused in workers."""
    result = grade(FIXTURES / "kill_zygote_ekf.py", "ekf_localization", workers=2)
    got = by_function(result)
    for fn in ("ekf_update", "associate_ml"):
        assert got[fn][0] == got[fn][1], (fn, got, [t.output[-300:] for t in result.tests if t.function == fn])
    assert got["ekf_predict"][0] == 0, got


SETOWN = """
import ctypes, fcntl, json, os

def owners(x):
    r, w = os.pipe()
    got = {}
    for name, call in (("F_SETOWN", lambda: fcntl.fcntl(r, 8, os.getppid())),
                       ("F_SETOWN_EX", lambda: fcntl.fcntl(r, 15, bytes(8))),
                       ("F_SETSIG", lambda: fcntl.fcntl(r, 10, 9)),
                       ("FIOSETOWN", lambda: fcntl.ioctl(r, 0x8901, (os.getppid()).to_bytes(4, "little"))),
                       ("SIOCSPGRP", lambda: fcntl.ioctl(r, 0x8902, (os.getppid()).to_bytes(4, "little")))):
        try:
            call()
            got[name] = "allowed"
        except OSError as exc:
            got[name] = exc.errno
    libc = ctypes.CDLL(None, use_errno=True)
    got["personality"] = libc.syscall(135 if os.uname().machine in ("x86_64", "amd64") else 92, 0xFFFFFFFF)
    print(json.dumps(got))
    return x
"""


@pytest.mark.parametrize("backend", [True, "bpf"])
def test_workers_cannot_name_another_process_as_owner_of_their_files(backend):
    """F_SETOWN, F_SETOWN_EX, F_SETSIG, FIOSETOWN, SIOCSPGRP and personality() are refused (both filter backends)."""
    if not _host_has_seccomp():
        pytest.skip("the kernel has no seccomp filters")
    lim = Limits(call_timeout=10.0, audit=False, **({} if backend is True else {"seccomp": backend}))
    (out,), ready = _sandbox_output(SETOWN, ["owners"], [("owners", [1.0])], lim)
    if backend == "bpf":
        assert ready["isolation"]["seccomp_backend"] == "bpf", ready["isolation"]
    got = _json_of(out)
    for name in ("F_SETOWN", "F_SETOWN_EX", "F_SETSIG", "FIOSETOWN", "SIOCSPGRP"):
        assert got[name] == 1, got  # EPERM
    assert got["personality"] == -1, got


FORGED = """
import json, os, struct, sys

def _res_fd():
    f = sys._getframe()
    while f is not None:
        if "res_fd" in f.f_locals:
            return f.f_locals["res_fd"]
        f = f.f_back

def forge(x):
    hdr = {"status": "ok", "result": {"t": "item", "value": {"t": "arr", "dtype": "<f8", "shape": [0, 2**62, 2**62],
           "off": 0, "len": 0, "py": "ndarray"}}, "error": None, "where": None, "mutated": [], "blocked": [],
           "elapsed": 0.0}
    h = json.dumps(hdr).encode()
    os.write(_res_fd(), b"AGW1" + struct.pack("<II", len(h), 0) + h)
    return x
"""


def test_a_forged_result_frame_is_a_protocol_error_and_ends_the_worker():
    """A frame numpy cannot shape is refused; the real frame behind it never answers a later call."""
    box = Sandbox([{"source": FORGED, "filename": "probe.py", "label": "probe"}], ["forge"],
                  Limits(call_timeout=10.0, audit=False))
    try:
        box.start()
        w = box.fork_worker()
        first = w.call("forge", [1.0], timeout=10.0)
        assert first.status == "protocol" and w.dead, (first.status, first.error)
        assert w.call("forge", [2.0], timeout=10.0).status == "crashed"
    finally:
        box.close()


def test_read_array_refuses_absurd_shapes():
    from autograder.wire import ProtocolError, _read_array

    for shape in ([0, 2**62, 2**62], [2**32], [0, 2**31 + 1], [2**16, 2**16, 0], [-1]):
        with pytest.raises(ProtocolError):
            _read_array({"dtype": "<f8", "shape": shape, "off": 0, "len": 0}, b"", np)
    assert _read_array({"dtype": "<f8", "shape": [0, 3], "off": 0, "len": 0}, b"", np).shape == (0, 3)


def _ends_the_sandbox_during_its_calls(monkeypatch, times):
    """The functions ``times`` (name -> how many calls, None: every call) end the whole sandbox during their calls:
    the sandbox is stopped, the request delivered into the worker's pipe, and the sandbox killed, so that the end
    comes once the call is under way and before any answer (as a function that signals its sandbox would, where
    nothing stops it). Returns the calls left to end."""
    real_exchange = sandbox_mod.Worker._exchange
    left = dict(times)

    def exchange(self, request, deadline, *rest):
        head = bytes(request[:4096]).replace(b" ", b"")
        for fn in left:
            if (left[fn] is None or left[fn] > 0) and self.sandbox.proc is not None and \
                    b'"fn":"' + fn.encode() + b'"' in head:
                if left[fn] is not None:
                    left[fn] -= 1
                os.killpg(self.sandbox.proc.pid, signal.SIGSTOP)  # no answer can come now
                assert os.write(self._req_w, request) > 0  # the call is under way ...
                os.killpg(self.sandbox.proc.pid, signal.SIGKILL)  # ... when the sandbox ends
                self.sandbox.proc.wait()
                return real_exchange(self, b"", deadline, *rest)
        return real_exchange(self, request, deadline, *rest)

    monkeypatch.setattr(sandbox_mod.Worker, "_exchange", exchange)
    return left


def test_a_function_that_ends_the_sandbox_loses_its_own_tests_only(monkeypatch):
    """The sandbox dies during every call of ekf_predict: ekf_predict scores 0, the other functions keep their
    marks (their reloads are not spent on it)."""
    _ends_the_sandbox_during_its_calls(monkeypatch, {"ekf_predict": None})
    result = grade(solution("ekf_localization"), "ekf_localization", workers=2)
    got = by_function(result)
    assert got["ekf_predict"][0] == 0, got
    for fn in ("ekf_update", "associate_ml"):
        assert got[fn][0] == got[fn][1], (fn, got, [t.output[-300:] for t in result.tests if t.function == fn])



# =========================================================================== the grader's own threads
def test_a_worker_closed_while_another_thread_restarts_the_sandbox_is_no_error():
    """Closing a worker (which asks the sandbox to end it) while another thread kills and restarts the sandbox
    never fails on the control socket the other thread is closing (a race that once cost a correct function a
    test: 'OSError: [Errno 9] Bad file descriptor')."""
    box = Sandbox([{"source": "def f(x):\n    return x\n", "filename": "f.py", "label": "f"}], ["f"],
                  Limits(call_timeout=10.0))
    errors, stop = [], threading.Event()

    def closer():
        while not stop.is_set():
            try:
                box.kill_worker(10**6)
            except Exception as exc:  # noqa: BLE001 - the failure under test
                errors.append(exc)
                return

    box.start()
    t = threading.Thread(target=closer)
    switch = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # the threads take turns between almost every bytecode: the race's window is open
    t.start()
    try:
        for _ in range(20):
            box.kill()
            box.start()
        w = box.fork_worker()
        got = w.call("f", [2.0], timeout=10.0)
        w.close()
    finally:
        stop.set()
        t.join()
        sys.setswitchinterval(switch)
        box.close()
    assert not errors, errors
    assert got.status == "ok" and float(got.returned.value.array) == 2.0, got


class _DeadBox:
    """A sandbox found dead at the next fork: what a thread sees when another function's call ended it."""

    def __init__(self):
        self.loads, self.dead, self.starts = 1, True, 0

    def fork_worker(self):
        if self.dead:
            raise engine_mod.ChildFailed(sandbox_mod.CallOutcome("crashed", error="the sandbox process is not running"))
        return "worker"

    def kill(self):
        pass

    def start(self):
        self.loads += 1
        self.starts += 1
        self.dead = False

    def ended(self, timeout=0.0):
        return self.dead


def _grading_with(box, inflight, reloads):
    g = engine_mod._Grading.__new__(engine_mod._Grading)
    g.box, g.lock, g.reloads, g.inflight, g.deaths, g.serial = box, threading.Lock(), reloads, dict(inflight), {}, None
    g.final = False
    return g


def test_a_death_first_seen_by_another_thread_is_charged_to_the_call_under_way():
    """The thread that finds the sandbox dead at its next fork may see the death before the thread whose call
    ended it: the death is still charged to that call (no reload spent), not refused for want of reloads."""
    box = _DeadBox()
    g = _grading_with(box, {"ekf_predict": 1, "ekf_update": 0}, reloads=engine_mod.MAX_RELOADS)
    assert g.fork_worker() == ("worker", 2)
    assert box.starts == 1 and g.reloads == engine_mod.MAX_RELOADS
    assert g.sandbox_died(1, "ekf_predict") == "alone"
    assert g.sandbox_died(1, "ekf_update") == "innocent"
    # a death between calls is no one's: it spends a reload, and once they are spent the machine is at fault
    box2 = _DeadBox()
    g2 = _grading_with(box2, {"ekf_predict": 0}, reloads=engine_mod.MAX_RELOADS - 1)
    assert g2.fork_worker() == ("worker", 2) and g2.reloads == engine_mod.MAX_RELOADS
    box2.dead = True
    with pytest.raises(engine_mod.GraderFault, match="no single call"):
        g2.fork_worker()
    # two calls under way: both are suspects, and from then on calls run one at a time
    g3 = _grading_with(_DeadBox(), {"ekf_predict": 1, "ekf_update": 1}, reloads=0)
    g3.fork_worker()
    assert g3.reloads == 1 and g3.serial is not None and g3.sandbox_died(1, "ekf_update") == "shared"


class _DyingWorker:
    """A worker whose call ends the whole sandbox."""

    dead, zygote_gone, gone_before_call = False, True, False

    def __init__(self, box):
        self.box = box

    def ended_between_calls(self):
        return False

    def call(self, *args, **kwargs):
        self.box.dead = True
        return sandbox_mod.CallOutcome("crashed", error="the process ended")

    def close(self):
        self.dead = True


class _SlowLoadingWorker:
    """A fresh worker that took 3 s to load the submission and, after its answer, looks ended (as a worker does
    that writes a stray byte after each answer): every call gets a fresh one."""

    dead, zygote_gone, gone_before_call = False, False, False

    def __init__(self):
        self.load_seconds = 0.0

    def ended_between_calls(self):
        return True

    def call(self, *args, **kwargs):
        self.load_seconds = 3.0
        return sandbox_mod.CallOutcome("ok", returned=None)

    def close(self):
        self.dead = True


def test_a_worker_s_loading_is_given_back_once_per_function_and_never_to_the_submission(monkeypatch):
    """A fresh worker loads the submission again, and that wait is no call's time. It is given back to the test's
    budget for the function's first worker only, and never to the submission's: a submission whose workers end
    after every answer and load slowly again pays for it (in the attack that found this, one test ran 232 s
    against its 30 s budget, and the grading 406 s against 240 s, with full marks)."""
    monkeypatch.setattr(engine_mod, "thread_delay", lambda: 0.0)  # the grader's own waiting: none here
    box = _DeadBox()
    box.dead = False
    box.fork_worker = lambda: _SlowLoadingWorker()
    g = _grading_with(box, {}, reloads=0)
    budget = engine_mod.Budget(test_budget=30.0, submission_budget=240.0)
    budget.start_test()
    test_deadline, submission_deadline = budget.test_deadline, budget.deadline
    caller = engine_mod._WorkerCaller(g, "ekf_predict", budget)
    for _ in range(5):
        assert caller.call("ekf_predict", [1.0], {}, timeout=1.0).status == "ok"
    assert budget.deadline == submission_deadline  # the submission's budget is a hard cap
    assert budget.test_deadline == test_deadline + 3.0  # one loading given back, not five


def test_a_call_that_ends_the_sandbox_counts_as_under_way_until_its_death_is_judged(monkeypatch):
    """Between the end of the call that killed the sandbox and the judgment of that death, another thread may find
    the sandbox dead at its next fork: the call must still count as under way then, or the death is charged to no
    one (a reload spent) and the function that caused it is judged innocent and run again."""
    box = _DeadBox()
    box.dead = False
    real_fork = box.fork_worker
    box.fork_worker = lambda: real_fork() and _DyingWorker(box)
    g = _grading_with(box, {}, reloads=0)
    seen = []
    real = g.sandbox_died

    def sandbox_died(generation, fn):
        seen.append(dict(g.inflight))
        return real(generation, fn)

    monkeypatch.setattr(g, "sandbox_died", sandbox_died)
    caller = engine_mod._WorkerCaller(g, "ekf_predict", None)
    out = caller.call("ekf_predict", [1.0], {}, timeout=1.0)
    assert seen == [{"ekf_predict": 1}] * 2, seen  # the call is run once more before it is charged
    assert out.status == "crashed" and "the sandbox ended during this call" in out.error
    assert caller.broken and g.inflight == {"ekf_predict": 0}


def test_one_death_of_the_sandbox_during_a_call_costs_nothing(monkeypatch):
    """A worker cannot signal its sandbox, so one death of the sandbox during a call is most likely the machine's
    (an out-of-memory kill): the call runs again in a new sandbox and the function keeps every mark. Only a
    function whose calls end the sandbox again is charged (test_a_function_that_ends_the_sandbox_loses_...)."""
    for workers in (1, 3):
        left = _ends_the_sandbox_during_its_calls(monkeypatch, {"ekf_update": 1, "associate_ml": 1})
        result = grade(solution("ekf_localization"), "ekf_localization", workers=workers)
        got = by_function(result)
        assert all(s == m for s, m in got.values()), (workers, got)
        assert left == {"ekf_update": 0, "associate_ml": 0}, left
        # the sandbox was loaded again; or, when the second death hit a sandbox loaded a moment before while
        # another thread forked from it (several workers, a loaded machine), the grading was done a second
        # time, one function at a time, in a new sandbox, and says so; the loadings of both gradings count
        assert result.loads >= 2, (workers, result.loads, result.notes)


def test_a_worker_killed_once_by_sigkill_costs_nothing_and_twice_costs_the_test(monkeypatch):
    """The kernel's out-of-memory killer ends a worker with SIGKILL, which no error of the function sends: the call
    runs once more in a new worker. A second such death is the function's (its test fails, as any crash)."""
    real_call = sandbox_mod.Worker.call
    kills = {"left": 1}

    def call(self, fn, *args, **kwargs):
        if fn == "ekf_update" and kills["left"] > 0:
            kills["left"] -= 1
            self.close()  # the worker is gone, as the zygote reports a worker killed from outside
            return sandbox_mod.CallOutcome(
                "crashed", error="the process running the function ended during the call (killed by signal SIGKILL)")
        return real_call(self, fn, *args, **kwargs)

    monkeypatch.setattr(sandbox_mod.Worker, "call", call)
    result = grade(solution("ekf_localization"), "ekf_localization", workers=1, functions=["ekf_update"])
    assert by_function(result)["ekf_update"] == (40.0, 40.0) and kills["left"] == 0
    kills["left"] = 2
    result = grade(solution("ekf_localization"), "ekf_localization", workers=1, functions=["ekf_update"])
    s, m = by_function(result)["ekf_update"]
    assert 0 < s < m and kills["left"] == 0, (s, m)
    assert "killed by signal SIGKILL" in result.tests[0].output


def test_a_loading_killed_once_by_sigkill_is_loaded_again(monkeypatch, tmp_path):
    """The kernel's out-of-memory killer may end the process loading a submission: the loading is tried once more
    (with a note), and the submission keeps every mark; killed again, the submission is graded again; killed in
    every loading of both gradings, every test fails naming the signal."""
    path = tmp_path / "slow_load.py"
    path.write_text("import time\ntime.sleep(1.0)\n" + solution_text("ekf_localization"))
    real = sandbox_mod.Sandbox._start_once
    kills = {"left": 1}

    def start_once(self, deadline):
        if kills["left"] > 0:
            kills["left"] -= 1

            def killer():
                time.sleep(0.4)  # while the submission's top level sleeps
                if self.proc is not None:
                    os.killpg(self.proc.pid, signal.SIGKILL)

            threading.Thread(target=killer, daemon=True).start()
        return real(self, deadline)

    monkeypatch.setattr(sandbox_mod.Sandbox, "_start_once", start_once)
    result = grade(path, "ekf_localization", workers=1, functions=["ekf_update"])
    assert by_function(result)["ekf_update"] == (40.0, 40.0) and kills["left"] == 0
    assert any("killed by signal SIGKILL) and the submission was loaded again" in n for n in result.notes), \
        result.notes
    kills["left"] = 2  # both loadings of the first grading: the submission is graded again
    result = grade(path, "ekf_localization", workers=1, functions=["ekf_update"])
    assert by_function(result)["ekf_update"] == (40.0, 40.0) and kills["left"] == 0
    assert any("graded a second time" in n for n in result.notes), result.notes
    assert result.loads == 3  # both gradings' loadings are counted: two killed, one that graded
    kills["left"] = 4  # every loading of both gradings: the loading fails, naming the signal
    result = grade(path, "ekf_localization", workers=1, functions=["ekf_update"])
    assert by_function(result)["ekf_update"][0] == 0 and kills["left"] == 0
    assert "killed by signal SIGKILL" in result.tests[0].output, result.tests[0].output


def test_a_sandbox_that_cannot_be_loaded_again_is_the_graders_fault_not_the_reloading_function():
    """The submission loaded once: a reload that fails (the loading killed twice) or a sandbox gone right after its
    reload is the machine's doing, never charged to the function that happened to need the reload."""
    box = _DeadBox()

    def start():
        raise engine_mod.ChildFailed(sandbox_mod.CallOutcome("crashed", error="ended unexpectedly (exit status 1)"))

    box.start = start
    g = _grading_with(box, {"ekf_predict": 1}, reloads=0)
    with pytest.raises(engine_mod.GraderFault, match="could not be loaded again"):
        g.fork_worker()
    box2 = _DeadBox()
    box2.start = lambda: setattr(box2, "loads", box2.loads + 1)  # loads, but the new sandbox is gone at once
    g2 = _grading_with(box2, {"ekf_predict": 1}, reloads=0)
    with pytest.raises(engine_mod.GraderFault, match="gone"):
        g2.fork_worker()


def test_a_sandbox_slow_to_end_is_still_a_death_of_the_sandbox():
    """The zygote is gone but the sandbox's outer process takes a while to end (a loaded machine): the death is
    judged as the sandbox's (run again), not as the function's own crash."""
    class SlowBox(_DeadBox):
        def ended(self, timeout=0.0):
            return timeout >= 1.5

    g = _grading_with(SlowBox(), {"ekf_update": 1}, reloads=0)
    assert g.sandbox_died(1, "ekf_update") == "alone"


def test_waiting_for_other_functions_calls_is_given_back_to_the_budget():
    """Once calls run one at a time, the time a function waits for another's call does not count against its test
    budget or the submission's."""
    g = _grading_with(_DeadBox(), {}, reloads=0)
    g.serial = threading.Lock()
    budget = engine_mod.Budget(30.0, 300.0)
    budget.start_test()
    before = (budget.test_deadline, budget.deadline)
    g.serial.acquire()
    threading.Timer(0.5, g.serial.release).start()
    with g.calling("ekf_update", budget):
        pass
    assert budget.test_deadline - before[0] >= 0.45 and budget.deadline - before[1] >= 0.45


ENDS_AFTER_ANSWERING = """import signal

def f(x):
    if x > 0:
        signal.signal(signal.SIGALRM, signal.SIG_DFL)
        signal.setitimer(signal.ITIMER_REAL, 0.3)  # the worker ends a moment after it has answered
    return float(x)
"""


def test_a_worker_that_ended_between_calls_is_replaced_before_the_next_call():
    """A worker killed after it answered (its end reported by the zygote, perhaps in the same read as the answer) is
    replaced before the next call, which then runs normally: that death is not the next call's."""
    box = Sandbox([{"source": ENDS_AFTER_ANSWERING, "filename": "ends.py", "label": "ends"}], ["f"],
                  Limits(call_timeout=10.0))
    try:
        box.start()
        w = box.fork_worker()
        assert w.call("f", [-1.0], timeout=10.0).status == "ok" and not w.ended_between_calls()
        first = w.call("f", [1.0], timeout=10.0)
        assert first.status == "ok" and float(first.returned.value.array) == 1.0
        deadline = time.monotonic() + 10
        while not w.ended_between_calls() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert w.ended_between_calls()
        w.close()
    finally:
        box.close()
    # through the engine: every second call of ekf_update kills its worker once it has answered
    real_call = sandbox_mod.Worker.call
    calls = {"n": 0}

    def call(self, fn, *args, **kwargs):
        out = real_call(self, fn, *args, **kwargs)
        if fn == "ekf_update":
            calls["n"] += 1
            if calls["n"] % 2 == 0:
                self.sandbox.kill_worker(self.id)  # the zygote ends it: the result pipe closes
                deadline = time.monotonic() + 10
                while not self.ended_between_calls() and time.monotonic() < deadline:  # ended before the next call
                    time.sleep(0.01)
        return out

    mp = pytest.MonkeyPatch()
    mp.setattr(sandbox_mod.Worker, "call", call)
    try:
        result = grade(solution("ekf_localization"), "ekf_localization", workers=1, functions=["ekf_update"])
    finally:
        mp.undo()
    assert by_function(result)["ekf_update"] == (40.0, 40.0) and calls["n"] > 8, (by_function(result), calls)


def test_deaths_of_the_sandbox_before_a_call_sends_its_request_cost_that_function_nothing(monkeypatch):
    """The sandbox is killed twice just before a call of ekf_update (no call under way): a death that came before
    the request could be written is not that call's, however often it happens (the reloads are the machine's)."""
    real = engine_mod._Grading.calling
    n = {"calls": 0}

    @contextlib.contextmanager
    def calling(self, fn, budget=None):
        if fn == "ekf_update":
            n["calls"] += 1
            if n["calls"] in (3, 6):
                os.killpg(self.box.proc.pid, signal.SIGKILL)
                self.box.proc.wait()
        with real(self, fn, budget) if budget is not None else real(self, fn):
            yield

    monkeypatch.setattr(engine_mod._Grading, "calling", calling)
    result = grade(solution("ekf_localization"), "ekf_localization", workers=1)
    assert all(s == m for s, m in by_function(result).values()), by_function(result)
    assert result.loads == 3 and n["calls"] > 6, (result.loads, n)


def test_a_sandbox_that_ends_after_every_loading_is_the_submissions_doing_in_the_second_grading(monkeypatch):
    """A sandbox that ends right after every loading, with no call under way (as top-level code that disturbs its
    own process can arrange), is first taken for the machine's doing (graded again); in the second grading it is the
    submission's: its functions fail with a message, and no internal error is raised on its account."""
    real = sandbox_mod.Sandbox._start_once

    def start_once(self, deadline):
        out = real(self, deadline)
        if out is None:
            proc = self.proc
            threading.Timer(0.05, lambda: os.killpg(proc.pid, signal.SIGKILL) if proc.poll() is None else None).start()
            proc.wait()  # ended before any call
        return out

    monkeypatch.setattr(sandbox_mod.Sandbox, "_start_once", start_once)
    result = grade(solution("ekf_localization"), "ekf_localization", workers=2)
    assert all(s == 0 for s, _ in by_function(result).values()), by_function(result)
    assert all("kept ending with no call under way" in t.output for t in result.tests), result.tests[0].output
    assert any("graded a second time" in n for n in result.notes), result.notes


def test_a_fault_of_the_grader_is_graded_again_never_a_failed_test(monkeypatch):
    """An exception of the grader's own machinery during a call (here an OSError from the worker's pipes) is no
    failed test: the submission is graded again, one function at a time, and the result says so; a fault that
    persists raises GraderFault (an internal error for the course staff), never a score."""
    real_call = sandbox_mod.Worker.call
    faults = {"left": 1}

    def call(self, fn, *args, **kwargs):
        if fn == "ekf_update" and faults["left"] > 0:
            faults["left"] -= 1
            raise OSError(9, "Bad file descriptor")
        return real_call(self, fn, *args, **kwargs)

    monkeypatch.setattr(sandbox_mod.Worker, "call", call)
    result = grade(solution("ekf_localization"), "ekf_localization", workers=2)
    got = by_function(result)
    assert all(s == m for s, m in got.values()), got
    assert any("internal error of the grader" in n and "Bad file descriptor" in n for n in result.notes), result.notes
    faults["left"] = 10**6
    with pytest.raises(engine_mod.GraderFault, match="Bad file descriptor"):
        grade(solution("ekf_localization"), "ekf_localization", workers=2, functions=["ekf_update"])


# =========================================================================== fork, isolate, then load
SHARED_AT_LOAD = """
import mmap, os
_SHM = mmap.mmap(-1, 4096)

def put(x):
    _SHM.seek(0)
    _SHM.write(b"from-another-function")
    return x

def get(x):
    _SHM.seek(0)
    print(repr(_SHM.read(21)))
    return x
"""


def test_memory_mapped_at_load_time_is_not_shared_between_functions():
    """Anonymous shared memory (or a pipe) made by top-level code is each worker's own: no channel between them."""
    box = Sandbox([{"source": SHARED_AT_LOAD, "filename": "probe.py", "label": "probe"}], ["put", "get"],
                  Limits(call_timeout=10.0))
    try:
        box.start()
        writer = box.fork_worker()  # alive while the other reads
        assert writer.call("put", [1.0], timeout=10.0).status == "ok"
        reader = box.fork_worker()
        got = reader.call("get", [1.0], timeout=10.0)
        reader.close()
        writer.close()
    finally:
        box.close()
    assert got.status == "ok", (got.status, got.error)
    assert "from-another-function" not in got.output, got.output


FORK_AT_LOAD = """
import os, resource
try:
    soft, hard = resource.getrlimit(resource.RLIMIT_NPROC)
    resource.setrlimit(resource.RLIMIT_NPROC, (hard, hard))
    pid = os.fork()
    if pid == 0:
        os._exit(0)
    os.waitpid(pid, 0)
    FORKED = 1.0
except OSError:
    FORKED = 0.0

def forked(x):
    return FORKED
"""


def test_top_level_code_cannot_start_processes_even_without_the_audit_hook():
    """Top-level code runs with a worker's limits (no new processes): it cannot raise RLIMIT_NPROC and fork."""
    iso = _iso()
    if not iso.get("root") or "uid_error" in iso:
        pytest.skip("needs root: RLIMIT_NPROC counts per uid")
    (out,), _ = _sandbox_output(FORK_AT_LOAD, ["forked"], [("forked", [1.0])],
                                Limits(call_timeout=10.0, audit=False, block_processes=False))
    assert out.status == "ok", (out.status, out.error)
    assert float(out.returned.value.array) == 0.0, out.returned.describe()
