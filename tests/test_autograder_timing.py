"""The grader's clocks count the submission's own time: not a loaded machine's waiting during the loadings, nor a
pause of the grader itself (attack round 34, F3 and F7).

Every test stages its situation (a waiting the kernel's accounting is made to report, a pause of the grader's own
process of a fixed length, a reply already in the pipe); none asserts how fast the machine is.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent / "autograder_fixtures"))

from agtest import solution_text  # noqa: E402

import autograder.engine as engine_mod  # noqa: E402
import autograder.sandbox as sandbox_mod  # noqa: E402
from autograder.sandbox import Limits, Sandbox, Worker  # noqa: E402
from autograder.wire import pack_frame  # noqa: E402

SLEEPER = "import time\n\ndef f(s):\n    time.sleep(s)\n    return 1.0\n"
SPINNER = ("import time\n\ndef f(s):\n    t = time.process_time() + s\n    while time.process_time() < t:\n"
           "        pass\n    return 1.0\n")


def _fake_waiting(monkeypatch, share):
    """The kernel's accounting replaced by a machine that keeps every process waiting ``share`` of the wall time."""
    t0 = time.monotonic()
    monkeypatch.setattr(sandbox_mod, "_delays", lambda pids: {p: share * (time.monotonic() - t0) for p in pids})


def _box(src, limits=None):
    return Sandbox([{"source": src, "filename": "p.py", "label": "p"}], ["f"], limits or Limits())


def _seccomp(ready):
    return bool((ready.get("isolation") or {}).get("seccomp"))


def _stop(pids, after, seconds):
    """SIGSTOP ``pids`` ``after`` seconds from now for ``seconds`` (from a process of its own session: the grader's
    pause, as Ctrl-Z, ``kill -STOP`` or ``docker pause`` make it)."""
    ids = " ".join(str(p) for p in pids)
    return subprocess.Popen(["/bin/sh", "-c", f"sleep {after}; kill -STOP {ids}; sleep {seconds}; kill -CONT {ids}"],
                            start_new_session=True)


# --------------------------------------------------------------------------- F7: a pause of the grader
class _StubSandbox:
    """What a Worker asks of its sandbox, for a worker whose pipes the test holds."""

    def __init__(self, load_timeout=0.0):
        self.limits = Limits()
        self.load_timeout = load_timeout
        self.ready, self.proc = None, None

    def kill_worker(self, wid):
        pass

    def ended(self, timeout=0.0):
        return False


def _staged_worker(load_timeout=0.0):
    """A Worker on pipes the test writes: ``(worker, write end of its result pipe, fds to close)``."""
    req_r, req_w = os.pipe()
    res_r, res_w = os.pipe()
    out_r, out_w = os.pipe()
    return Worker(_StubSandbox(load_timeout), 1, req_w, res_r, out_r), res_w, (req_r, res_w, out_w)


def test_a_reply_already_in_the_pipe_when_the_time_is_up_is_the_answer():
    """F7 (1): a grader that was paused found its call's deadline passed and declared a timeout without reading the
    result pipe, which held the worker's reply (a call of 40 ms "did not finish within 10 s"). The pipe is now read
    once more, without waiting, before the time is called."""
    worker, res_w, fds = _staged_worker()
    try:
        os.write(res_w, pack_frame({"status": "ok", "returned": 1.0}))
        header, _, status, err = worker._exchange(b"", time.monotonic() - 5.0)
        assert status == "ok" and header["returned"] == 1.0, (status, err)
    finally:
        worker.close(kill=False)
        for fd in fds:
            os.close(fd)


def test_a_worker_s_word_that_it_loaded_already_in_the_pipe_is_taken():
    """The same for a worker's loading: its word "loaded" in the pipe when the grader comes back is no timeout."""
    worker, res_w, fds = _staged_worker(load_timeout=0.0)
    try:
        os.write(res_w, pack_frame({"status": "loaded"}))
        assert worker._await_loaded() is None and worker.loaded
    finally:
        worker.close(kill=False)
        for fd in fds:
            os.close(fd)


def test_a_pause_of_the_grader_before_it_sent_the_request_is_no_one_s_time(monkeypatch):
    """F7: the grader paused (stopped, or starved) after a call's clock started and before it sent the request:
    the call was a timeout before its worker had even been asked. The grader's own lateness (a wait returning, or
    the grader coming back to its clock, more than LATE late) now stretches the deadline and is given back to the
    budgets. Staged: the grader's thread does nothing for 2 s there, as a stopped process would."""
    real = Worker._exchange

    def paused(self, *args, **kwargs):
        time.sleep(2.0)
        return real(self, *args, **kwargs)

    box = _box(SLEEPER)
    try:
        ready = box.start()
        if not _seccomp(ready):
            pytest.skip("the grader's lateness is counted only where the sandbox holds seccomp")
        worker = box.fork_worker()
        assert worker.call("f", [0.0], timeout=5.0).status == "ok"  # loaded
        monkeypatch.setattr(Worker, "_exchange", paused)
        out = worker.call("f", [0.2], timeout=1.0)
        assert out.status == "ok", (out.status, out.error)
        assert out.waited >= 1.5, out.waited  # handed to the budgets
    finally:
        box.close()


def test_without_seccomp_the_grader_s_lateness_is_not_counted(monkeypatch):
    """Where a process of the sandbox could signal the grader (no seccomp), a pause of the grader is no leniency: the
    submission could stop the grader and go on computing."""
    real = Worker._exchange

    def paused(self, *args, **kwargs):
        time.sleep(1.5)
        return real(self, *args, **kwargs)

    box = _box(SLEEPER, Limits(seccomp=False))
    try:
        box.start()
        worker = box.fork_worker()
        assert worker.call("f", [0.0], timeout=5.0).status == "ok"
        monkeypatch.setattr(Worker, "_exchange", paused)
        out = worker.call("f", [2.0], timeout=1.0)
        assert out.status == "timeout" and out.waited == 0.0, (out.status, out.waited)
    finally:
        box.close()


def test_a_pause_of_the_grader_and_its_worker_is_no_one_s_time():
    """F7 (2): the grader's whole process group stopped (Ctrl-Z, docker pause) during a call: the worker did not run,
    and the call timed out. Staged: the grader and its worker stopped 2.5 s during a call of 0.5 s of processor
    time whose limit is 1.5 s."""
    box = _box(SPINNER)
    helper = None
    try:
        ready = box.start()
        if not _seccomp(ready):
            pytest.skip("the grader's lateness is counted only where the sandbox holds seccomp")
        worker = box.fork_worker()
        assert worker.call("f", [0.0], timeout=5.0).status == "ok"  # loaded: its process is known
        pids = worker._own_pids()
        assert len(pids) == 1, pids
        helper = _stop([os.getpid(), pids[0]], 0.2, 2.5)
        out = worker.call("f", [0.5], timeout=1.5)
        helper.wait(timeout=30)
        assert out.status == "ok", (out.status, out.error)
        assert out.waited >= 1.5, out.waited
    finally:
        if helper is not None and helper.poll() is None:
            helper.wait(timeout=30)
        box.close()


def test_a_paused_loading_reads_what_arrived_before_calling_the_time():
    """The loading's clock too: a grader paused while the submission loaded found the loading's deadline passed and
    declared the loading too long, with its end already sent. Staged without seccomp (no lateness counted there): the
    grader stopped 4 s from 0.1 s into a loading of about a second whose limit is 2.5 s."""
    box = _box("import time\ntime.sleep(0.3)\n\ndef f():\n    return 1.0\n",
               Limits(seccomp=False, import_timeout=2.5, statement_timeout=2.0))
    helper = _stop([os.getpid()], 0.1, 4.0)
    try:
        ready = box.start()
        assert ready is not None and not box.cut and not box.skip, ready
    finally:
        helper.wait(timeout=30)
        box.close()


# --------------------------------------------------------------------------- F3: the loadings' waiting
def test_the_loadings_measure_their_waiting(monkeypatch):
    """F3: the loadings' waiting for a processor stretched their deadlines and went nowhere else. It is now kept
    (the sandbox's first loading, and each worker's) for the budgets."""
    src = "import time\ntime.sleep(0.5)\n\ndef f(s):\n    return 1.0\n"
    _fake_waiting(monkeypatch, 0.8)
    box = _box(src)
    try:
        ready = box.start()
        if not _seccomp(ready):
            pytest.skip("the waiting is counted only where the sandbox holds seccomp")
        assert box.waited >= 0.8 * 0.5, box.waited
        worker = box.fork_worker()
        assert worker.call("f", [0.0], timeout=5.0).status == "ok"
        assert worker.load_waited >= 0.8 * 0.5, worker.load_waited
    finally:
        box.close()


class _Box:
    loads, dead = 1, False

    def __init__(self, make):
        self.fork_worker = make

    def ended(self, timeout=0.0):
        return False


class _LoadingWorker:
    """A fresh worker that took 3 s to load the submission, 2 s of it waiting for a processor; after its answer it
    looks ended, so every call gets a fresh one."""

    dead, zygote_gone, gone_before_call = False, False, False

    def __init__(self):
        self.load_seconds = self.load_waited = 0.0

    def ended_between_calls(self):
        return True

    def call(self, *args, **kwargs):
        self.load_seconds, self.load_waited = 3.0, 2.0
        return sandbox_mod.CallOutcome("ok", returned=None)

    def close(self):
        self.dead = True


def test_a_worker_s_waiting_while_loading_is_given_back_to_the_budgets(monkeypatch):
    """F3: a correct notebook with slow top-level cells scored 100 idle and 55 with two busy processes beside it: the
    submission's budget paid every loading's waiting for a processor. That waiting now comes back: to the
    submission's budget always, to the test's for the workers after the first (whose whole loading the test gets
    back already); the own loading time stays charged."""
    monkeypatch.setattr(engine_mod, "thread_delay", lambda: 0.0)  # the grader's own waiting: none here
    g = engine_mod._Grading.__new__(engine_mod._Grading)
    g.box, g.lock, g.reloads, g.inflight, g.deaths, g.serial, g.final = (_Box(_LoadingWorker), threading.Lock(), 0,
                                                                         {}, {}, None, False)
    budget = engine_mod.Budget(test_budget=30.0, submission_budget=240.0)
    budget.start_test()
    test_deadline, submission_deadline = budget.test_deadline, budget.deadline
    caller = engine_mod._WorkerCaller(g, "ekf_predict", budget)
    for _ in range(5):
        assert caller.call("ekf_predict", [1.0], {}, timeout=1.0).status == "ok"
    assert budget.deadline == pytest.approx(submission_deadline + 5 * 2.0)
    assert budget.test_deadline == pytest.approx(test_deadline + 3.0 + 4 * 2.0)
    assert budget.waited == pytest.approx(10.0)


def test_the_first_loading_s_waiting_is_given_back_to_every_function_s_budget(tmp_path, monkeypatch):
    """F3: the submission's budget runs from before the first loading (the grader's checks): what of that loading
    was no one's comes back to each function's budget."""
    budgets = []

    class Recorded(engine_mod.Budget):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            budgets.append(self)

    real_start = Sandbox.start

    def start(self):
        ready = real_start(self)
        self.waited = getattr(self, "waited", 0.0) + 50.0  # as if the machine had kept the loading waiting 50 s
        return ready

    monkeypatch.setattr(engine_mod, "Budget", Recorded)
    monkeypatch.setattr(Sandbox, "start", start)
    path = tmp_path / "sub.py"
    path.write_text(solution_text("particle_filter"))
    fns = ["normalize_log_weights", "effective_sample_size"]
    result = engine_mod.grade(path, "particle_filter", functions=fns)
    assert result.score == result.max_score > 0, [t.output for t in result.tests if t.score < t.max_score]
    assert len(budgets) == 2
    for b in budgets:
        assert b.waited >= 50.0, b.waited
        assert b.deadline == pytest.approx(b.start + b.submission_budget + b.waited)


def test_the_worker_s_waiting_is_its_own_not_the_zygote_s():
    """F3's measurement: the zygote holds a new worker's request pipe from the fork request until it has forked, and
    the grader, looking for the process reading that pipe, could take the zygote for the worker: from then on it
    measured the zygote's waiting (none) for that worker's loading and calls (in the reproducer, 2 workers of 7
    "did not finish loading within 3 s" with 0.01 s of waiting). A process that holds the control socket too is not
    the worker. Staged: a "zygote" holding the pipe and the socket, its child holding the pipe alone."""
    req_r, req_w = os.pipe()
    mine, theirs = __import__("socket").socketpair()
    worker_src = "import time; time.sleep(30)"
    zygote_src = (f"import subprocess, sys, time; subprocess.Popen([sys.executable, '-c', {worker_src!r}], "
                  f"pass_fds=({req_r},)); time.sleep(30)")
    runner = subprocess.Popen([sys.executable, "-c", f"import subprocess, sys, time; subprocess.Popen([sys.executable, "
                               f"'-c', {zygote_src!r}], pass_fds=({req_r}, {theirs.fileno()})); time.sleep(30)"],
                              pass_fds=(req_r, theirs.fileno()), start_new_session=True)
    try:
        os.close(req_r)
        deadline = time.monotonic() + 15
        while len(sandbox_mod._descendants(runner.pid)) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        zygote, worker_pid = sandbox_mod._descendants(runner.pid)[:2]
        box = _StubSandbox()
        box.proc, box.ready = runner, {"isolation": {"seccomp": True}}
        box._ctl_link = f"socket:[{os.fstat(theirs.fileno()).st_ino}]"
        res_r, res_w = os.pipe()
        out_r, out_w = os.pipe()
        worker = Worker(box, 1, req_w, res_r, out_r)
        assert worker._own_pids() == [worker_pid], (worker._own_pids(), zygote, worker_pid)
        worker.close(kill=False)
        for fd in (res_w, out_w):
            os.close(fd)
    finally:
        os.killpg(runner.pid, 9)
        runner.wait()
        mine.close()
        theirs.close()


def test_the_functions_share_the_submission_s_no_one_s_time():
    """The functions' budgets all run from the grading's start: graded one after another (one worker, as on a
    one-processor machine), the last waited through every earlier function's waiting, but was given back only its
    own (in the reproducer, 75/100 with every loading's waiting measured and given back). The submission's budget
    now gets every function's waiting back, for all of them, within the one cap over the grading."""
    from autograder.sandbox import MAX_STRETCH

    shared = engine_mod.NoOnesTime(100.0)
    first, last = (engine_mod.Budget(30.0, 100.0, start=0.0, shared=shared) for _ in range(2))
    last.start_test()
    test_deadline = last.test_deadline
    first.give_back_waiting(5.0)
    assert last.deadline == first.deadline == 105.0 and last.waited == 5.0
    assert last.test_deadline == test_deadline  # a test's budget gets its own function's waiting only
    first.extend(2.0)  # time one function waited for another's calls is its own to get back
    assert first.deadline == 107.0 and last.deadline == 105.0
    last.give_back_waiting(10 * MAX_STRETCH * 100.0)
    assert first.deadline == 100.0 + MAX_STRETCH * 100.0 + 2.0 and last.deadline == 100.0 + MAX_STRETCH * 100.0


# --------------------------------------------------------------------------- the grader's own computing
def test_the_grader_s_own_waiting_between_calls_is_given_back(monkeypatch):
    """On a loaded machine the grader's thread waits for a processor while it computes a test's scenarios and
    expected values between calls: that was charged to the test's and the submission's budgets (a correct
    bundle_adjustment submission lost two tests at load 4-6). It is given back before each call and each test."""
    waited = [0.0]
    monkeypatch.setattr(engine_mod, "thread_delay", lambda: waited[0])
    b = engine_mod.Budget(10.0, 100.0)
    b.start_test()
    test_end, end = b.test_deadline, b.deadline
    waited[0] = 4.0  # the grader's thread waited 4 s since the test began
    b.catch_up()
    assert b.test_deadline == pytest.approx(test_end + 4.0) and b.deadline == pytest.approx(end + 4.0)
    b.catch_up()  # counted once
    assert b.test_deadline == pytest.approx(test_end + 4.0)
    waited[0] = 1e9  # capped with the rest of the no one's time
    b.catch_up()
    assert b.waited == pytest.approx(engine_mod.MAX_STRETCH * 100.0)
    # where the kernel does not say, nothing is given back
    monkeypatch.setattr(engine_mod, "thread_delay", lambda: None)
    b = engine_mod.Budget(10.0, 100.0)
    b.start_test()
    b.catch_up()
    assert b.waited == 0.0


def test_every_call_and_test_catches_up_with_the_grader_s_waiting(tmp_path, monkeypatch):
    """The give-back happens where a budget is judged: before each call's limit and each test's start."""
    looks = []
    real = engine_mod.Budget.catch_up
    monkeypatch.setattr(engine_mod.Budget, "catch_up", lambda self: (looks.append(1), real(self))[1])
    path = tmp_path / "sub.py"
    path.write_text(solution_text("particle_filter"))
    result = engine_mod.grade(path, "particle_filter", functions=["normalize_log_weights"])
    assert result.score == result.max_score > 0
    calls = sum(int(t.output.split("(")[1].split()[0]) for t in result.tests if t.output.startswith("passed ("))
    assert len(looks) >= calls + len(result.tests), (len(looks), calls, len(result.tests))


def test_the_kernel_reports_the_grader_thread_s_waiting():
    """thread_delay reads this thread's own accounting: a number of seconds that only grows."""
    a = sandbox_mod.thread_delay()
    if a is None:
        pytest.skip("the kernel keeps no scheduler statistics here")
    assert isinstance(a, float) and a >= 0 and sandbox_mod.thread_delay() >= a


def test_the_first_loading_gives_back_the_grader_s_pauses_only_where_seccomp_held(monkeypatch):
    """The first loading counted the grader's lateness (and its processes' waiting) when seccomp had been asked
    for, not when it held (a filter that failed to install): they are given back only where the sandbox's report
    says seccomp held, as for the workers (round 10, O1). Staged: every look at the clock finds the grader 7 s late,
    and the kernel says every process waits 80 % of the time."""
    def lap(self, asked=0.0):
        self.late = 7.0  # counted whatever was asked for

    monkeypatch.setattr(sandbox_mod._Waiting, "lap", lap)
    _fake_waiting(monkeypatch, 0.8)
    box = _box("def f(s):\n    return 1.0\n", Limits(seccomp=False))
    try:
        ready = box.start()
        assert not _seccomp(ready)
        assert box.waited == 0.0, box.waited
    finally:
        box.close()


# --------------------------------------------------------------------------- a pause between calls
def test_a_pause_of_the_grader_between_calls_is_given_back():
    """Between two calls the grader's thread computes (scenarios, expected values): time it neither computed nor
    waited for a processor in was a pause of the grader, given back with ``count_pauses`` (where seccomp holds)
    and only when over LATE; its own computing stays charged."""
    b = engine_mod.Budget(10.0, 100.0, count_pauses=True)
    w0 = time.monotonic()
    b.start_test()
    test_end, end = b.test_deadline, b.deadline
    time.sleep(1.0)  # neither computing nor waiting for a processor: as a stopped process
    b.catch_up()
    wall = time.monotonic() - w0
    assert 0.9 <= b.test_deadline - test_end <= wall and b.deadline - end == pytest.approx(b.test_deadline - test_end)
    b.between_calls()
    got, w0, c0 = b.waited, time.monotonic(), time.thread_time()
    while time.thread_time() < c0 + 1.0:  # the grader's own computing: no one gives that back
        pass
    b.catch_up()
    # what comes back is at most the wall time the thread did not compute (a loaded machine's waiting)
    assert b.waited - got <= (time.monotonic() - w0) - (time.thread_time() - c0) + 0.05
    b = engine_mod.Budget(10.0, 100.0)  # count_pauses=False: nothing of it
    b.start_test()
    time.sleep(1.0)
    b.catch_up()
    assert b.waited < 0.5


@pytest.mark.parametrize("seccomp", [True, False])
def test_a_pause_of_the_grader_computing_expected_values_costs_no_test(tmp_path, monkeypatch, seccomp):
    """The grader's process stopped for 2 s (SIGSTOP) while it computed an expected value between two calls of a
    test whose budget is 1 s: the correct submission keeps the test where seccomp holds. Without seccomp a process
    of the sandbox could stop the grader, so the pause is charged (the test then runs out of its budget)."""
    import slamlib as sl

    real, paused = sl.normalize_log_weights, []

    def pausing(log_w):
        if not paused:
            paused.append(1)
            _stop([os.getpid()], 0.0, 2.0).wait()
        return real(log_w)

    path = tmp_path / "sub.py"
    path.write_text(solution_text("particle_filter"))
    limits = Limits(test_budget=1.0, seccomp=seccomp)
    probe = _box(SLEEPER, Limits(seccomp=seccomp))
    try:
        held = _seccomp(probe.start())
    finally:
        probe.close()
    if seccomp and not held:
        pytest.skip("seccomp is not available here")
    monkeypatch.setattr(sl, "normalize_log_weights", pausing)
    result = engine_mod.grade(path, "particle_filter", functions=["normalize_log_weights"], limits=limits, workers=1)
    first = result.tests[0]
    assert paused
    if seccomp:
        assert result.score == result.max_score, [t.output for t in result.tests]
    else:
        assert first.score == 0 and "time budget of 1 s was used up" in first.output, first.output
