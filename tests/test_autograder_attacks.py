"""Hostile submissions are contained: they cost the attacking function its points and nothing else.

Each attack replaces ``normalize_log_weights`` in a correct particle-filter
solution (or adds top-level code); the grade of the correct
``effective_sample_size`` must not change, ``results.json`` must stay valid, and
no process may outlive grading. Timeouts are short (2.5 s) to keep the suite fast.
"""

from __future__ import annotations

import json
import os
import socket
import sys
import threading
import time
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent / "autograder_fixtures"))

from agtest import gradescope_json_ok, replace_function, solution_text  # noqa: E402

from autograder.engine import grade  # noqa: E402
from autograder.results import write_json_atomic  # noqa: E402
from autograder.sandbox import Limits, isolation_report  # noqa: E402

LIMITS = Limits(call_timeout=2.5, import_timeout=8.0)
TARGET = "normalize_log_weights"
OTHER = "effective_sample_size"
MARKER = "1000.4242"


def _runner_children():
    """Live processes started by this test process that run the grader's child script."""
    out = []
    me = str(os.getpid())
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        ppid = stat.rsplit(")", 1)[1].split()[1]
        if (ppid == me and "_runner.py" in cmd) or MARKER in cmd:
            out.append(cmd)
    return out


@pytest.fixture(autouse=True)
def _secret(tmp_path_factory, monkeypatch):
    """Grading secrets of the test run live in a temporary folder, not in the user's config."""
    monkeypatch.setenv("AUTOGRADER_SECRET_FILE", str(tmp_path_factory.getbasetemp() / "grading_secret"))


@pytest.fixture(autouse=True)
def no_leftover_processes():
    yield
    deadline = time.monotonic() + 5
    while _runner_children() and time.monotonic() < deadline:
        time.sleep(0.1)
    assert _runner_children() == []


def attack(tmp_path, body=None, *, top="", limits=LIMITS, function=TARGET):
    """Grade the solution with ``function`` replaced by ``body`` and ``top`` prepended; check containment."""
    text = solution_text("particle_filter")
    if body is not None:
        text = replace_function(text, function, body)
    path = tmp_path / "attack.py"
    path.write_text("import os\nimport sys\nimport numpy as np\n" + top + "\n" + text)
    t0 = time.monotonic()
    result = grade(path, "particle_filter", limits=limits, functions=[function, OTHER])
    elapsed = time.monotonic() - t0
    res = tmp_path / "results" / "results.json"
    write_json_atomic(res, result.to_gradescope())
    data = gradescope_json_ok(json.loads(res.read_text()))
    assert {t["name"].split(":")[0] for t in data["tests"]} == {function, OTHER}
    scores = result.by_function()
    if function != OTHER:
        assert scores[OTHER] == (15.0, 15.0), result.text_report()
    outputs = "\n".join(t.output for t in result.tests if t.function == function)
    return scores[function], outputs, result, elapsed


# --------------------------------------------------------------------------- exits and crashes
def test_fake_results_then_os_exit_at_import(tmp_path):
    fake = tmp_path / "results" / "results.json"
    top = f"""
import json
for p in ("results.json", {str(fake)!r}, "/autograder/results/results.json"):
    try:
        os.makedirs(os.path.dirname(p) or ".", exist_ok=True)
        with open(p, "w") as fh:
            json.dump({{"score": 100, "tests": []}}, fh)
    except OSError:
        pass
os._exit(0)
"""
    text = "import os\n" + top + solution_text("particle_filter")
    path = tmp_path / "attack.py"
    path.write_text(text)
    result = grade(path, "particle_filter", limits=LIMITS)
    write_json_atomic(fake, result.to_gradescope())
    data = gradescope_json_ok(json.loads(fake.read_text()))
    assert data["score"] == 0 and len(data["tests"]) == 15
    assert all("ended unexpectedly (exit status 0)" in t["output"] for t in data["tests"])


def test_os_exit_during_a_call(tmp_path):
    (s, m), out, _, _ = attack(tmp_path, "def normalize_log_weights(log_w):\n    os._exit(3)\n")
    assert s == 0 and m == 20
    assert "ended during the call (exit status 3)" in out


def test_sys_exit_in_function_and_at_top_level(tmp_path):
    (s, _), out, _, _ = attack(tmp_path, "def normalize_log_weights(log_w):\n    sys.exit(0)\n")
    assert s == 0 and "sys.exit" in out
    (s, _), _, result, _ = attack(tmp_path, top="sys.exit(1)\n")
    assert s == 20  # a top-level exit is only a skipped statement
    assert any("called sys.exit()" in n for n in result.notes)


def test_segfault(tmp_path):
    body = "def normalize_log_weights(log_w):\n    import ctypes\n    return ctypes.string_at(0)\n"
    (s, _), out, _, _ = attack(tmp_path, body, limits=Limits(call_timeout=2.5, audit=False, block_processes=False))
    assert s == 0 and "killed by signal SIGSEGV" in out


# --------------------------------------------------------------------------- hangs and resource exhaustion
def test_infinite_loop_ignoring_signals_times_out(tmp_path):
    body = ("def normalize_log_weights(log_w):\n    import signal\n"
            "    for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGALRM):\n"
            "        signal.signal(sig, signal.SIG_IGN)\n    while True:\n        pass\n")
    (s, _), out, result, elapsed = attack(tmp_path, body)
    assert s == 0
    assert "did not finish within 2.5 s" in out and "not run: an earlier call" in out
    assert elapsed < 20


def test_input_gets_end_of_file(tmp_path):
    (s, _), out, _, elapsed = attack(tmp_path, "def normalize_log_weights(log_w):\n    return input()\n")
    assert s == 0 and "EOFError" in out and elapsed < 20


def test_memory_bomb(tmp_path):
    body = ("def normalize_log_weights(log_w):\n    hog = []\n    while True:\n"
            "        hog.append(np.ones(10**7))\n")
    (s, _), out, _, _ = attack(tmp_path, body)
    assert s == 0 and ("MemoryError" in out or "did not finish" in out)
    (s, _), out, _, _ = attack(tmp_path, "def normalize_log_weights(log_w):\n    return np.ones((10**6, 10**6))\n")
    assert s == 0 and "MemoryError" in out


def test_print_flood(tmp_path):
    body = "def normalize_log_weights(log_w):\n    while True:\n        print('x' * 10000)\n"
    (s, _), out, _, elapsed = attack(tmp_path, body)
    assert s == 0 and "printed more than 1048576 bytes" in out and elapsed < 20


FORK = f"""
def normalize_log_weights(log_w):
    pids = []
    for _ in range(3):
        pid = os.fork()
        if pid == 0:
            os.execv("/bin/sleep", ["sleep", "{MARKER}"])
        pids.append(pid)
    w = np.exp(log_w - log_w.max())
    return w / w.sum()
"""


def test_fork_bomb_is_refused_by_the_audit_hook(tmp_path):
    (s, _), out, _, _ = attack(tmp_path, FORK)
    assert s == 0 and "os.fork is not allowed while grading" in out


def test_fork_bomb_is_refused_by_the_os_limits(tmp_path):
    iso = isolation_report(Limits(audit=False))
    if iso.get("root") and "uid_error" in iso:
        pytest.skip("running as root without the possibility to drop privileges: RLIMIT_NPROC does not apply")
    (s, _), out, _, _ = attack(tmp_path, FORK, limits=Limits(call_timeout=2.5, audit=False, block_processes=False))
    assert s == 0 and ("Resource temporarily unavailable" in out or "BlockingIOError" in out), out


def test_signalling_the_grader_is_refused(tmp_path):
    body = f"def normalize_log_weights(log_w):\n    os.kill({os.getpid()}, 9)\n"
    (s, _), out, _, _ = attack(tmp_path, body)
    assert s == 0 and "os.kill is not allowed" in out
    iso = isolation_report(Limits(audit=False))
    if iso.get("pidns") or (iso.get("root") and "uid_error" not in iso):
        # without the hook: the grader's pid does not exist in the child's PID namespace, and its uid differs
        (s, _), out, _, _ = attack(tmp_path, body, limits=Limits(call_timeout=2.5, audit=False,
                                                                  block_processes=False))
        assert s == 0 and ("ProcessLookupError" in out or "PermissionError" in out), out


def test_signals_cannot_leave_the_pid_namespace(tmp_path):
    iso = isolation_report(Limits(audit=False))
    if not iso.get("pidns"):
        pytest.skip("no PID namespace on this machine")
    body = ("def normalize_log_weights(log_w):\n    import signal\n"
            f"    fd = os.pidfd_open({os.getpid()})\n    signal.pidfd_send_signal(fd, signal.SIGKILL)\n")
    (s, _), out, _, _ = attack(tmp_path, body, limits=Limits(call_timeout=2.5, audit=False, block_processes=False))
    # refused by the PID namespace (no such process) or, before that, by the seccomp filter (no pidfds in workers)
    assert s == 0 and ("No such process" in out or "Invalid argument" in out or "ProcessLookupError" in out
                       or "Operation not permitted" in out), out


def test_no_network(tmp_path):
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(5)
    server.settimeout(0.2)
    port = server.getsockname()[1]
    accepted = []

    def serve():
        end = time.monotonic() + 15
        while time.monotonic() < end:
            try:
                conn, _ = server.accept()
                accepted.append(conn)
            except (TimeoutError, OSError):
                continue

    th = threading.Thread(target=serve, daemon=True)
    th.start()
    body = (f"def normalize_log_weights(log_w):\n    import socket\n"
            f"    socket.create_connection(('127.0.0.1', {port}), timeout=1).sendall(b'stolen')\n")
    try:
        (s, _), out, _, _ = attack(tmp_path, body)
        assert s == 0 and "socket.connect is not allowed" in out
        iso = isolation_report(Limits(audit=False))
        if iso.get("netns"):
            (s, _), out, _, _ = attack(tmp_path, body, limits=Limits(call_timeout=2.5, audit=False,
                                                                      block_processes=False))
            assert s == 0 and ("unreachable" in out or "refused" in out), out
    finally:
        time.sleep(0.3)
        server.close()
    assert accepted == []


# --------------------------------------------------------------------------- tampering and garbage results
def test_monkeypatched_numpy_comparisons_do_not_help(tmp_path):
    top = """
np.allclose = lambda *a, **k: True
np.isclose = lambda *a, **k: True
np.array_equal = lambda *a, **k: True
np.testing.assert_allclose = lambda *a, **k: None
np.ndarray = type("Fake", (), {})
"""
    body = "def normalize_log_weights(log_w):\n    return np.zeros(len(log_w))\n"
    (s, _), out, _, _ = attack(tmp_path, body, top=top)
    assert s == 0 and "w is wrong" in out


def test_objects_that_equal_everything(tmp_path):
    body = """
class Liar:
    def __eq__(self, other):
        return True
    def __float__(self):
        return 1.0


def effective_sample_size(w):
    return Liar()
"""
    (s, m), out, _, _ = attack(tmp_path, body, function=OTHER)
    assert s == 0 and m == 15 and "dtype object" in out


def test_ndarray_subclasses_are_judged_as_plain_arrays(tmp_path):
    sub = """
class Sneaky(np.ndarray):
    def __eq__(self, other):
        return np.ones(np.shape(self), bool)
    def __sub__(self, other):
        return np.zeros(np.shape(self))
    __rsub__ = __sub__
    def __array_finalize__(self, obj):
        pass
"""
    good = sub + "\n\ndef normalize_log_weights(log_w):\n    w = np.exp(log_w - log_w.max())\n    return (w / w.sum()).view(Sneaky)\n"
    (s, _), out, _, _ = attack(tmp_path, good)
    assert s == 20 and "ndarray subclass (Sneaky)" in out
    bad = sub + "\n\ndef normalize_log_weights(log_w):\n    return np.zeros(len(log_w)).view(Sneaky)\n"
    (s, _), out, _, _ = attack(tmp_path, bad)
    assert s == 0 and "w is wrong" in out


@pytest.mark.parametrize("ret, message", [
    ("np.full(len(log_w), np.nan)", "contains NaN or inf"),
    ("np.ones(len(log_w)) / len(log_w) + 0j", "must be real; got a complex dtype"),
    ("np.array([object()] * len(log_w))", "dtype object"),
    ("(np.ones(len(log_w)) / len(log_w))[None, :]", "must have shape"),
    ("np.float64(1.0)", "must have shape"),
    ("np.ones(len(log_w), dtype=bool)", "real floating dtype"),
    ("np.zeros(10**7)", "too large"),
    ("'weights'", "has dtype <U7"),
])
def test_garbage_results(tmp_path, ret, message):
    (s, _), out, _, _ = attack(tmp_path, f"def normalize_log_weights(log_w):\n    return {ret}\n")
    assert s == 0 and message in out, out


def test_broadcastable_scalar_for_a_float_result(tmp_path):
    body = "def effective_sample_size(w):\n    w = np.asarray(w)\n    return np.array([w.sum()**2 / (w**2).sum()])\n"
    (s, _), out, _, _ = attack(tmp_path, body, function=OTHER)
    assert s == 0 and "must have shape ()" in out


def test_corrupting_the_result_channel(tmp_path):
    body = ("def normalize_log_weights(log_w):\n    for fd in range(3, 64):\n        try:\n"
            "            os.write(fd, b'AGW1garbage' * 10)\n        except OSError:\n            pass\n"
            "    return np.ones(len(log_w)) / len(log_w)\n")
    (s, _), out, _, _ = attack(tmp_path, body)
    assert s == 0 and "could not read the function's result" in out


def test_modified_arguments_are_reported_and_still_judged(tmp_path):
    body = ("def normalize_log_weights(log_w):\n    log_w -= log_w.max()\n    w = np.exp(log_w)\n"
            "    return w / w.sum()\n")
    (s, _), out, _, _ = attack(tmp_path, body)
    assert s == 20 and "modified its argument log_w" in out


# --------------------------------------------------------------------------- using slamlib or the autograder
def test_static_slamlib_use_earns_nothing(tmp_path):
    body = "def normalize_log_weights(log_w):\n    return sl.normalize_log_weights(log_w)\n"
    (s, _), out, _, _ = attack(tmp_path, body, top="import slamlib as sl\n")
    assert s == 0 and "No credit" in out and "`sl` (import slamlib" in out


def test_dynamic_slamlib_import_earns_nothing(tmp_path):
    body = ("def normalize_log_weights(log_w):\n    import importlib\n"
            "    return importlib.import_module('slam' + 'lib').normalize_log_weights(log_w)\n")
    (s, _), out, _, _ = attack(tmp_path, body)
    assert s == 0 and "No credit" in out and "import slamlib" in out


def test_reading_slamlib_source_earns_nothing(tmp_path):
    import slamlib

    src = str(Path(slamlib.__file__).parent / "particle.py")
    body = (f"def normalize_log_weights(log_w):\n    ns = {{}}\n    exec(open({src!r}).read(), ns)\n"
            "    return ns['normalize_log_weights'](log_w)\n")
    (s, _), out, _, _ = attack(tmp_path, body)
    assert s == 0 and "No credit" in out and "open " in out


def test_self_check_cell_importing_the_autograder_is_harmless(tmp_path):
    top = "from autograder.selfcheck import run_public_tests\n"
    tail = "\nrun_public_tests('particle_filter', globals())\n"
    text = "import os\nimport sys\nimport numpy as np\n" + top + solution_text("particle_filter") + tail
    path = tmp_path / "nb.py"
    path.write_text(text)
    result = grade(path, "particle_filter", limits=LIMITS, functions=[TARGET, OTHER])
    assert result.score == 35
    assert any("refused while loading: import autograder" in n for n in result.notes)


# --------------------------------------------------------------------------- the grader run by an unprivileged user
NOBODY_DRIVER = """
import json, sys
sys.path[:0] = {paths!r}
from autograder.engine import grade
from autograder.sandbox import Limits
result = grade({sub!r}, "particle_filter", functions=["normalize_log_weights", "effective_sample_size"],
               limits=Limits(call_timeout=3.0, audit={audit}, block_processes={audit}))
print(json.dumps({{"scores": result.by_function(), "isolation": result.isolation,
                  "outputs": [t.output for t in result.tests]}}))
"""


_UNHIDE = """T=$1; B=$2; C=$3; shift 3
mkdir -p "$T/$C" && mount --bind "$B/$C" "$T/$C" && mount --rbind "$T" "$B" && exec "$@"
"""


def _nobody_python(tmp):
    """A command prefix running this environment's Python as the user nobody, or None.

    When the interpreter lives under a folder only root may enter (``/root/.pyenv``),
    a private mount namespace shows that folder's one needed entry through a
    world-readable stand-in; nothing on the host changes.
    """
    import shutil
    import subprocess
    import numpy

    setpriv = shutil.which("setpriv")
    if os.geteuid() != 0 or not setpriv:
        return None, None
    paths = [str(Path(__file__).resolve().parents[1]), str(Path(numpy.__file__).resolve().parents[1])]
    drop = [setpriv, "--reuid=65534", "--regid=65534", "--clear-groups"]
    wrappers = [[]]
    prefix = Path(sys.prefix).resolve()
    blocked = next((p for p in reversed(prefix.parents) if p != Path("/") and not os.stat(p).st_mode & 0o001), None)
    if blocked is not None and shutil.which("unshare"):
        stand_in = Path(tmp) / "stand-in"
        stand_in.mkdir(mode=0o755)
        child = prefix.relative_to(blocked).parts[0]
        script = Path(tmp) / "unhide.sh"
        script.write_text(_UNHIDE)
        wrappers.append([shutil.which("unshare"), "-m", "sh", str(script), str(stand_in), str(blocked), child])
    minor = f"python{sys.version_info[0]}.{sys.version_info[1]}"
    for wrap in wrappers:
        for py in dict.fromkeys([sys.executable, shutil.which(minor), f"/usr/bin/{minor}", f"/usr/local/bin/{minor}"]):
            if not py:
                continue
            cmd = wrap + drop + [py, "-c",
                                 f"import sys; sys.path[:0] = {paths!r}; import numpy, scipy, nbformat, autograder.engine; "
                                 f"assert sys.version_info[:2] == {tuple(sys.version_info[:2])!r}; "
                                 "import subprocess; subprocess.run([sys.executable, '-c', 'pass'], check=True)"]
            if subprocess.run(cmd, capture_output=True, cwd="/").returncode == 0:
                return wrap + drop + [py], paths
    return None, None


@pytest.mark.parametrize("audit", [True, False])
def test_grading_as_an_unprivileged_user(audit):
    """Run as nobody: the layers that do not need root still contain a fork, the network and signals."""
    import subprocess
    import tempfile

    work = Path(tempfile.mkdtemp(prefix="ag-nobody-"))
    try:
        os.chmod(work, 0o755)
        prefix, paths = _nobody_python(work)
        if prefix is None:
            pytest.skip("needs root, setpriv and a Python interpreter the user nobody can run")
        # first try to kill the grader (found through /proc) with kill() and pidfd_send_signal(), then fork
        hunt = ("    import signal\n    for d in os.listdir('/proc'):\n        try:\n"
                "            if b'autograder.engine' in open(f'/proc/{d}/cmdline', 'rb').read():\n"
                "                signal.pidfd_send_signal(os.pidfd_open(int(d)), signal.SIGKILL)\n"
                "        except Exception:\n            pass\n        try:\n"
                "            if b'autograder.engine' in open(f'/proc/{d}/cmdline', 'rb').read():\n"
                "                os.kill(int(d), signal.SIGKILL)\n"
                "        except Exception:\n            pass\n")
        body = FORK.replace("    pids = []\n", hunt + "    pids = []\n")
        text = replace_function(solution_text("particle_filter"), TARGET, body)
        sub = work / "attack.py"
        sub.write_text("import os\nimport numpy as np\n" + text)
        os.chmod(sub, 0o644)
        (work / "secret").write_text("0123456789abcdef0123456789abcdef\n")
        os.chmod(work / "secret", 0o644)
        driver = NOBODY_DRIVER.format(paths=paths, sub=str(sub), audit=audit)
        p = subprocess.run(prefix + ["-c", driver], capture_output=True, text=True, cwd="/tmp",
                           env={"PATH": "/usr/bin:/bin", "HOME": "/tmp",
                                "AUTOGRADER_SECRET_FILE": str(work / "secret")}, timeout=120)
        assert p.returncode == 0, p.stderr
        data = json.loads(p.stdout.strip().splitlines()[-1])
    finally:
        import shutil

        shutil.rmtree(work, ignore_errors=True)
    assert data["scores"]["normalize_log_weights"][0] == 0
    assert data["scores"]["effective_sample_size"] == [15.0, 15.0]
    iso = data["isolation"]
    assert iso["root"] is False and iso["rlimits"]["RLIMIT_NPROC"] == 0
    out = "\n".join(data["outputs"])
    if audit:
        assert "os.fork is not allowed" in out
    else:
        assert "Resource temporarily unavailable" in out or "BlockingIOError" in out, out
