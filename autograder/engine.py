"""Grading one submission: static checks, one sandbox per submission, a fresh worker per function, the tests.

:func:`grade` never raises on account of the submission: a file that cannot be
read, a syntax error, a missing function, a crash, a hang or garbage output all
end as failed tests with a message, and every function keeps its ``max_score``.

The submission is loaded once, in one :class:`~autograder.sandbox.Sandbox`; each
contract function is graded in a worker process forked from it (and forked again
after a crash or a timeout), so slow top-level code runs once and one function's
state never leaks into another's. Every function's public tests run before any
function's hidden test starts (a worker serves its function's tests in order, so
nothing a student sees before the due date can depend on a hidden test). Scenarios come from a seed derived from the
deployment's secret and the submission's content (:mod:`autograder.seeds`), and
time is bounded per call, per test and per submission.

Deaths are judged by when they happen; the machine's doing is never a reason
for a zero:

- A worker, or the whole sandbox, that ended between two calls (after its answer,
  or before the next request could be written) is replaced before the next call
  at no cost to anyone: the answers it gave stand.
- When the whole sandbox ends during a call, or the worker alone is killed by
  SIGKILL, the call is run again once (in a new sandbox, or a new worker): workers
  may not signal the sandbox, and a function's own error does not send SIGKILL, so
  such a death is most often the machine's (an out-of-memory kill, say). If the
  sandbox ends again during a call of a function whose call was the only one under
  way, that function is charged with it: its remaining tests score 0, and the
  sandbox is loaded again for the others at no cost to them.
- When several calls were under way, each is run again once in the new sandbox,
  and from then on calls run one at a time so that the next death has a single
  suspect; the time a function waits for the others' calls is given back to its
  budgets.
- A loading that ends abruptly is tried once more. Deaths no call can be charged
  with are allowed ``MAX_RELOADS`` reloads. Beyond them, when a submission that
  loaded once cannot be loaded again, or when its loading ended abruptly twice, the
  machine is first taken to be at fault (:class:`SandboxLost`: graded again); in the
  second grading the same end is the submission's (its top-level code can disturb
  its own sandbox), and the functions it stops fail with a message.
- A :class:`GraderFault` (the grader's own machinery failed) is never a failed
  test: :func:`grade` grades the submission again, one function at a time, and
  raises if that fails too, so that the command reports an internal error for the
  course staff instead of a score.
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
import traceback
import zlib
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from .context import CallError, Ctx, Fail, SkipRest
from .exercises import EXERCISES, get_exercise
from .results import GradeResult, TestResult
from .sandbox import LATE, MAX_STRETCH, CallOutcome, ChildFailed, Limits, Sandbox, thread_delay
from .spec import VISIBILITY
from .submission import FORBIDDEN, SubmissionError, forbidden_usage, load_submission

__all__ = ["grade", "GradeResult", "TestResult", "run_tests", "Budget", "GraderFault", "SandboxLost"]

#: A worker that died is forked again at most this many times per function.
MAX_RESTARTS = 3
#: The sandbox itself (the loaded submission) is started again at most this many times per grading for deaths
#: no single function can be blamed for (a death during the call of one function alone ends that function's
#: tests instead, and costs the others nothing).
MAX_RELOADS = 2
#: A call whose worker (or sandbox) had ended before its request was sent is run in a new one at most this many
#: times (the sandbox's own ends are bounded by MAX_RELOADS and the charges; this bounds a worker's).
MAX_GONE = 5
#: Seconds to wait for the sandbox to end after a worker's result pipe closed with no word from the zygote.
ZYGOTE_GONE_WAIT = 5.0


def _test_seed(exercise, test_name, base):
    return [int(base), int(zlib.crc32(f"{exercise}/{test_name}".encode()))]


def _zero_all(ex, message, functions=None):
    return [TestResult(t.name, t.function, 0.0, t.weight, message, VISIBILITY[t.visibility]) for t in ex.tests
            if functions is None or t.function in functions]


def _call_failure_text(err):
    o = err.outcome
    lines = [f"called {err.call_text}"]
    if o.status == "error":
        lines.append(f"it raised {o.error}")
        if o.where:
            lines.append(o.where)
    else:
        lines.append(o.error or o.status)
    if o.output and o.status in ("error", "crashed", "output", "timeout"):
        tail = o.output.strip()[-600:]
        if tail:
            lines.append("its output ended with:\n" + "\n".join("  | " + ln for ln in tail.splitlines()[-8:]))
    return "\n".join(lines)


def check_integer(value, name, minimum, *, optional=True):
    """``value`` as given: None (when ``optional``) or an integer of at least ``minimum``, else a ValueError naming
    the argument (a bool, a float or a negative seed would be coerced into another grading)."""
    if value is None and optional:
        return value
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name}: expected {'None or ' if optional else ''}an integer of at least {minimum}, "
                         f"got {value!r}")
    return value


class GraderFault(Exception):
    """The grader's own machinery failed during a call (not the submission): never a failed test.

    :func:`grade` grades the submission once more, one function at a time; a second fault propagates, so the
    command reports an internal error for the course staff instead of a score.
    """


class SandboxLost(GraderFault):
    """The sandbox kept ending with no call to charge it to (or its loading ended abruptly).

    Most often the machine's doing, so the first grading raises it and the submission
    is graded again; in that second grading the same end is the submission's (its
    top-level code can end or disturb its own sandbox), and the functions it stops
    fail with a message instead.
    """


class NoOnesTime:
    """The seconds of a grading that were no one's (a loaded machine's waiting for a processor, the grader's own
    pauses), given back to the submission's budget: shared by its functions' budgets, which all run from the same
    start (a function graded after another waited through the other's waiting too). At most ``MAX_STRETCH`` times
    the submission's budget over the grading: waiting measured at once in two functions (graded side by side) may
    be counted twice, never past that cap."""

    def __init__(self, submission_budget):
        self.cap = MAX_STRETCH * float(submission_budget)
        self.seconds = 0.0
        self._lock = threading.Lock()

    def take(self, seconds):
        """Add ``seconds`` (as much of it as the cap leaves); return how much was added."""
        with self._lock:
            got = min(max(0.0, float(seconds)), max(0.0, self.cap - self.seconds))
            self.seconds += got
            return got


class Budget:
    """Wall-time budgets: one per test (reset by :meth:`start_test`) and one for the whole submission (``shared``:
    the :class:`NoOnesTime` of the grading, which its functions' budgets share).

    ``count_pauses``: the grader thread's time between calls that was neither its computing nor its waiting for a
    processor (its process stopped, ``docker pause``, or the thread kept from running by the grader's other
    threads) is given back too (:meth:`catch_up`). Only where seccomp holds: elsewhere a process of the sandbox
    could stop the grader itself and compute meanwhile.
    """

    def __init__(self, test_budget, submission_budget, start=None, shared=None, count_pauses=False):
        self.test_budget = float(test_budget)
        self.submission_budget = float(submission_budget)
        self.start = time.monotonic() if start is None else start
        self.shared = shared if shared is not None else NoOnesTime(self.submission_budget)
        self._deadline = self.start + self.submission_budget  # and what extend() gave this function alone
        self.test_deadline = None
        self._grader_waited = None  # the grader thread's waiting for a processor when last looked at (catch_up)
        self.count_pauses = bool(count_pauses)
        self._between = None  # (wall, thread CPU, thread waiting) when the grader's thread last stopped calling

    @property
    def deadline(self):
        """When the submission's budget ends for this function: its start and budget, the time it waited for other
        functions' calls (extend), and the grading's time that was no one's (give_back_waiting)."""
        return self._deadline + self.shared.seconds

    @property
    def waited(self):
        """Seconds of no one's time given back to the submission's budget so far, over the grading."""
        return self.shared.seconds

    def start_test(self, budget=None):
        self.test_deadline = time.monotonic() + float(budget or self.test_budget)
        self.current = float(budget or self.test_budget)
        self._grader_waited = thread_delay()
        self.between_calls()

    def between_calls(self):
        """The grader's thread is between calls (a call returned, or a test starts): until its next call it computes
        the test's scenarios and expected values, none of the submission's work."""
        if self.count_pauses:  # waiting and computing read before the wall clock here, after it in catch_up: they
            # bracket the wall interval, so a wait between two readings is subtracted, never counted twice
            d, c = thread_delay(), time.thread_time()
            self._between = (time.monotonic(), c, d)
        else:
            self._between = None

    def catch_up(self):
        """Give back the time the grader's own thread (this one) has waited for a processor since the test began or
        since the last call: its computing between a test's calls (scenarios, expected values) on a loaded machine
        is no one's time either. With ``count_pauses``, so is the time between calls that the thread neither
        computed nor waited for a processor, when over ``LATE`` (a pause: the grader's own work between calls does
        not block)."""
        before = self._grader_waited
        if before is not None:
            now = thread_delay()
            if now is not None and now > before:
                self._grader_waited = now
                self.give_back_waiting(now - before)
        if self._between is not None:
            t1 = time.monotonic()
            c1 = time.thread_time()
            d1 = thread_delay()
            t0, c0, d0 = self._between
            self.between_calls()  # counted once
            paused = (t1 - t0) - (c1 - c0) - (d1 - d0 if d0 is not None and d1 is not None else 0.0)
            if paused > LATE:
                self.give_back_waiting(paused)

    @property
    def exhausted(self):
        return time.monotonic() >= self.deadline

    def limit(self, timeout):
        """``(seconds, reason)``: the call's time limit and which budget (if any) shortened it."""
        now = time.monotonic()
        limit, reason = float(timeout), None
        if self.test_deadline is not None and self.test_deadline - now < limit:
            limit, reason = self.test_deadline - now, "test"
        if self.deadline - now < limit:
            limit, reason = self.deadline - now, "submission"
        return limit, reason

    def forgive(self, seconds):
        """Give the current test back ``seconds`` (a fresh worker's loading of the submission): the submission's own
        budget stays a hard cap."""
        if self.test_deadline is not None:
            self.test_deadline += seconds

    def extend(self, seconds):
        """Give back ``seconds`` the function spent waiting for other functions' calls (not its own time)."""
        self._deadline += seconds
        if self.test_deadline is not None:
            self.test_deadline += seconds

    def give_back_waiting(self, seconds, test=True):
        """Give back ``seconds`` that were no one's: a loaded machine kept the submission's processes waiting for a
        processor (during a call or a loading), or the grader itself was paused. To the submission's budget of every
        function (they share it: :class:`NoOnesTime`), and to this function's test's. At most ``MAX_STRETCH`` times
        the submission's budget over the whole grading, so a grading ends however loaded the machine (or however a
        submission might make its workers wait). ``test=False``: to the submission's budget only (the test's got
        the time back otherwise: :meth:`forgive`)."""
        seconds = self.shared.take(seconds)
        if test and self.test_deadline is not None:
            self.test_deadline += seconds

    def message(self, reason):
        if reason == "submission":
            return (f"the submission's time budget of {self.submission_budget:g} s was used up (grading stops "
                    "there; the remaining tests score 0)")
        return (f"the test's time budget of {self.current:g} s was used up: the function is too slow for this "
                "test (the other tests still run)")


class _WorkerCaller:
    """Routes a test's calls to a worker forked for one function, forking a fresh one after a crash."""

    def __init__(self, grading, fn, budget):
        self.grading = grading
        self.fn = fn
        self.budget = budget
        self.worker = None
        self.started = 0
        self.timed_out = False
        self.broken = None
        self.generation = None
        self.load_forgiven = False  # the first worker's loading of the submission was given back to the test
        self.retried = False  # a call of this function was run again after a death shared with other calls
        self.forgiven = False  # ... after a death during its call alone

    def call(self, fn, args, kwargs, **kw):
        try:
            return self._call(fn, args, kwargs, **kw)
        finally:
            if self.budget is not None:
                self.budget.between_calls()

    def _call(self, fn, args, kwargs, *, timeout, names=(), global_seed=None, _gone=0):
        if self.broken:
            return CallOutcome("skipped", error=self.broken)
        if self.budget is not None:
            self.budget.catch_up()
        limit, reason = self.budget.limit(timeout) if self.budget else (timeout, None)
        if limit <= 0:
            return CallOutcome("timeout", error=self.budget.message(reason), budget=reason)
        if self.worker is not None and not self.worker.dead and self.worker.ended_between_calls():
            # a worker that ended after its previous call returned (its end reported, or its pipe closed with its
            # sandbox) is replaced before this call at no cost: its answers stand. A sandbox that ended without its
            # worker's pipe showing it yet is caught when this call's turn comes (ended_since below).
            self.worker.close()
            self.worker = None
            self.started -= 1
        if self.worker is None or self.worker.dead:
            if self.started > MAX_RESTARTS:
                self.broken = f"not run: the process running {self.fn} died {self.started} times"
                return CallOutcome("skipped", error=self.broken)
            try:
                self.worker, self.generation = self.grading.fork_worker()
            except SandboxLost as exc:
                if not self.grading.final:
                    raise
                self.broken = (f"not run: the sandbox holding the submission kept ending with no call under way "
                               f"({exc}; graded twice). Does the top-level code end or alter its own process?")
                return CallOutcome("crashed", error=self.broken)
            except GraderFault:
                raise
            except Exception as exc:  # the grader's machinery (or the machine), not the submission
                raise GraderFault(f"starting a worker for {self.fn}: {type(exc).__name__}: {exc}") from exc
            self.started += 1
            if self.budget is not None and hasattr(self.grading, "reload_waited"):
                self.budget.give_back_waiting(self.grading.reload_waited())
        blame = None
        try:
            with self.grading.calling(self.fn, self.budget):
                if self.grading.ended_since(self.generation, exclude=self.fn):  # while this call waited its turn
                    out, blame = CallOutcome("crashed", error="the sandbox had ended before the call"), "before"
                else:
                    loaded = getattr(self.worker, "load_seconds", 0.0)
                    load_waited = getattr(self.worker, "load_waited", 0.0)
                    out = self.worker.call(fn, args, kwargs, timeout=max(limit, 0.001), names=names,
                                           global_seed=global_seed)
                    first = not self.load_forgiven
                    if (self.budget is not None and not self.load_forgiven
                            and getattr(self.worker, "load_seconds", 0.0) > loaded):
                        # the function's first worker loading the submission is no test's time (never the
                        # call's: its deadline starts after); once per function, so a submission that makes its
                        # workers end and load again and again pays for it from its budgets
                        self.budget.forgive(self.worker.load_seconds - loaded)
                        self.load_forgiven = True
                    if self.budget is not None and getattr(self.worker, "load_waited", 0.0) > load_waited:
                        # what of the worker's loading was no one's (the machine kept it waiting for a processor,
                        # or the grader was paused) is given back to the submission's budget, and to the test's
                        # where forgive() did not give it the whole loading
                        self.budget.give_back_waiting(self.worker.load_waited - load_waited,
                                                      test=not (first and self.load_forgiven))
                    if self.budget is not None and getattr(out, "waited", 0.0) > 0:
                        # the time a loaded machine kept the worker waiting for a processor is no one's: the
                        # call's deadline was stretched by it, and so are the test's and the submission's budgets
                        self.budget.give_back_waiting(out.waited)
                    if out.status == "crashed" and self.worker.gone_before_call:
                        blame = "before"
                    elif out.status == "crashed" and self.worker.zygote_gone:
                        # judged while this call still counts as under way: a thread that finds the sandbox dead at
                        # its next fork in the meantime must count this call among the suspects
                        blame = self.grading.sandbox_died(self.generation, self.fn)
        except Exception as exc:  # Worker.call turns everything the submission can do into an outcome
            raise GraderFault(f"calling {fn}: {type(exc).__name__}: {exc}") from exc
        if (blame is None and out.status == "crashed" and not self.forgiven
                and "killed by signal SIGKILL" in (out.error or "")):
            # the worker alone was killed, by a signal a function's own error does not send (the kernel's
            # out-of-memory killer sends it): perhaps the machine's doing, so once, the call runs again
            blame = "alone"
        if blame == "before" and _gone < MAX_GONE:
            # the worker (or its sandbox) had ended before the request was sent: not this call's doing; the death
            # is judged by the calls under way now, and the call runs in a new worker
            self.grading.ended_since(self.generation)
            self.worker.close()
            self.worker = None
            self.started -= 1
            return self.call(fn, args, kwargs, timeout=timeout, names=names, global_seed=global_seed,
                             _gone=_gone + 1)
        if blame == "before":
            blame = None
        if blame is not None:
            if blame == "alone" and not self.forgiven:  # perhaps the machine's doing: once, the call runs again
                self.forgiven = True
                self.worker.close()
                self.worker = None
                self.started -= 1
                return self.call(fn, args, kwargs, timeout=timeout, names=names, global_seed=global_seed)
            if blame == "alone" and self.worker.zygote_gone:  # the sandbox ended during a call of it alone, twice
                self.worker.close()
                self.worker = None
                self.broken = (f"not run: the sandbox ended during a call of {self.fn} (a function that ends the "
                               "sandbox gets no points for the tests after it)")
                out.error = f"{out.error}; the sandbox ended during this call"
                return out
            if blame == "innocent" or (blame == "shared" and not self.retried):
                # caught in another function's crash (or perhaps so): run the call again in the new sandbox
                self.retried = self.retried or blame == "shared"
                self.worker.close()
                self.worker = None
                self.started -= 1
                return self.call(fn, args, kwargs, timeout=timeout, names=names, global_seed=global_seed)
        if out.status == "timeout":
            if reason:
                out.error = self.budget.message(reason)
                out.budget = reason
            else:
                self.timed_out = True
        if self.worker.dead:
            self.worker = None
        return out

    def close(self):
        if self.worker is not None:
            self.worker.close()
            self.worker = None


def run_tests(ex, fn, caller, *, seed=None, limits=None, budget=None, tests=None, state=None):
    """Run every test of ``fn`` (or only ``tests``, in their order) through ``caller``; return TestResults and
    blocked attempts.

    ``state`` (a dict) carries what ends a function's grading from one run to the next of the same function's
    other tests: a call that hung, a used-up budget or ``NotImplementedError`` leaves the tests after it not run.
    """
    results = []
    blocked = []
    state = {} if state is None else state
    skip_reason = state.get("skip")
    cap = limits.call_timeout if (limits and limits.call_timeout) else None
    for test in (ex.tests_for(fn) if tests is None else tests):
        vis = VISIBILITY[test.visibility]
        if budget is not None:
            budget.catch_up()
        if budget is not None and budget.exhausted and not skip_reason:
            skip_reason = "not run: " + budget.message("submission")
        if skip_reason:
            results.append(TestResult(test.name, fn, 0.0, test.weight, skip_reason, vis))
            continue
        timeout = min(test.timeout, cap) if cap else test.timeout
        if budget is not None:
            budget.start_test(test.budget)
        s = _test_seed(ex.name, test.name, ex.seed if seed is None else seed)
        ctx = Ctx(caller, fn, ex.params(fn), timeout, np.random.default_rng(s), s)
        try:
            test.run(ctx)
            score, text = test.weight, f"passed ({ctx.calls} call{'s' if ctx.calls != 1 else ''})"
        except Fail as exc:
            score, text = 0.0, "FAILED\n" + str(exc)
        except CallError as exc:
            score, text = 0.0, "FAILED\n" + _call_failure_text(exc)
            if exc.outcome.status == "timeout":
                if exc.outcome.budget == "submission":
                    skip_reason = "not run: " + budget.message("submission")
                elif exc.outcome.budget is None:
                    skip_reason = (f"not run: an earlier call of {fn} timed out (a function that hangs gets no points "
                                   "for the tests after it)")
            elif exc.outcome.status == "error" and str(exc.outcome.error or "").startswith("NotImplementedError"):
                skip_reason = f"not run: {fn} raised NotImplementedError in '{test.title}' (not implemented yet)"
        except SkipRest as exc:
            score, text = 0.0, str(exc)
        except GraderFault:  # the grader's failure, not the submission's: no score from it
            raise
        except (MemoryError, OSError) as exc:  # the grader's own process (the machine): no score from it either
            raise GraderFault(f"the grader's process, in {test.name!r}: {type(exc).__name__}: {exc}") from exc
        except Exception as exc:  # noqa: BLE001 - a bug in a test must not end grading
            score = 0.0
            text = ("FAILED\nthe grader could not complete this test "
                    f"({type(exc).__name__}: {exc}); this is likely caused by an unusual result"
                    + (f"\nlast call: {ctx.last_call}" if ctx.last_call else ""))
            if os.environ.get("AUTOGRADER_DEBUG"):
                text += "\n" + traceback.format_exc()
        if score == 0.0 and test.hint:
            text += f"\nHint: {test.hint}"
        if ctx.mutated:
            text += (f"\nNote: {fn} modified its argument{'s' if len(ctx.mutated) > 1 else ''} "
                     f"{', '.join(sorted(ctx.mutated))}; contract functions must not modify their arguments "
                     "(the values were still judged)")
        for n in dict.fromkeys(ctx.notes):
            text += f"\nNote: {n}"
        blocked.extend(ctx.blocked)
        results.append(TestResult(test.name, fn, score, test.weight, text, vis))
    state["skip"] = skip_reason
    return results, blocked


class _Grading:
    """The sandbox of one submission, shared by the functions' threads (started again if it dies)."""

    def __init__(self, sub, functions, limits, final=False):
        self.box = Sandbox(sub.units, functions, limits, sub.display_name)
        self.final = final  # the second grading: an end of the sandbox no call can be charged with is the code's
        self.lock = threading.Lock()
        self.reloads = 0
        self.inflight = {}  # function -> calls under way
        self.deaths = {}  # sandbox generation -> the functions that had calls under way when it ended
        self.serial = None  # once a death could not be blamed on one function, calls run one at a time

    def start(self):
        return self.box.start()

    def fork_worker(self):
        """A fresh worker and the generation (load count) of the sandbox it came from."""
        try:
            with self.lock:
                generation = self.box.loads
                return self.box.fork_worker(), generation
        except ChildFailed:
            with self.lock:
                if self.box.loads == generation:  # the sandbox that refused the fork is gone: start it again
                    self.box.kill()
                    # the death is judged now, by the calls under way, even when this thread is the first to see it
                    # (the thread whose call ended it may not have noticed yet)
                    if len(self._suspects(generation)) != 1:  # no single function to charge it to
                        if self.reloads >= MAX_RELOADS:
                            raise SandboxLost(f"the sandbox ended {self.reloads + 1} times with no single call to "
                                              "charge it to (the machine's doing)") from None
                        self.reloads += 1
                    before = getattr(self.box, "waited", 0.0)
                    try:
                        self.box.start()
                    except ChildFailed as exc:  # it loaded before: a loading that fails now is not the code's doing
                        raise SandboxLost(f"the submission could not be loaded again ({exc.outcome.error})") from None
                    # what of that loading was no one's: given back to the budgets of the thread that waited for it
                    # (taken by reload_waited)
                    self._local().reload_waited = (getattr(self._local(), "reload_waited", 0.0)
                                                   + getattr(self.box, "waited", 0.0) - before)
                try:
                    return self.box.fork_worker(), self.box.loads
                except ChildFailed as exc:
                    raise SandboxLost(f"a sandbox loaded a moment ago is gone ({exc.outcome.error})") from None

    def _local(self):
        local = self.__dict__.get("_thread")
        if local is None:
            local = self.__dict__.setdefault("_thread", threading.local())
        return local

    def reload_waited(self):
        """Seconds of the sandbox's loadings this thread started again (fork_worker) that were no one's, since the
        last time it asked."""
        local = self._local()
        got, local.reload_waited = getattr(local, "reload_waited", 0.0), 0.0
        return got

    def ended_since(self, generation, exclude=None):
        """True when sandbox ``generation`` has ended (its death, first seen now, is charged to the calls under way,
        not counting one call of ``exclude``, whose request has not been sent)."""
        with self.lock:
            if generation != self.box.loads:
                return True
            if not self.box.ended(timeout=0.0):
                return False
            self._suspects(generation, exclude=exclude)
            return True

    def _suspects(self, generation, fn=None, exclude=None):
        """The functions charged with the death of sandbox ``generation``: those with calls under way when it was
        first seen dead (and ``fn``, whose call saw it; not one call of ``exclude``, which had sent nothing). Call
        with ``self.lock`` held."""
        if generation not in self.deaths:
            self.deaths[generation] = {f for f, n in self.inflight.items() if n - (f == exclude) > 0} | (
                {fn} if fn else set())
            if len(self.deaths[generation]) > 1 and self.serial is None:
                self.serial = threading.Lock()
        return self.deaths[generation]

    @contextlib.contextmanager
    def calling(self, fn, budget=None):
        serial = self.serial
        if serial is not None:
            t0 = time.monotonic()
            serial.acquire()
            if budget is not None:  # the time spent waiting for the other functions' calls is not this one's
                budget.extend(time.monotonic() - t0)
        with self.lock:
            self.inflight[fn] = self.inflight.get(fn, 0) + 1
        try:
            yield
        finally:
            with self.lock:
                self.inflight[fn] -= 1
            if serial is not None:
                serial.release()

    def sandbox_died(self, generation, fn):
        """After a crashed call of ``fn``: None when the sandbox lives on (the worker alone died); ``"alone"`` when
        the sandbox ended while only ``fn`` had a call under way, ``"shared"`` when other calls were under way too,
        ``"innocent"`` when ``fn`` had no call under way when it ended."""
        with self.lock:
            if generation not in self.deaths:
                # the result pipe closed with no word from the zygote: the sandbox is ending, or (rarely) the
                # zygote could not write that word; a loaded machine may take seconds to tear a sandbox down
                if generation == self.box.loads and not self.box.ended(timeout=ZYGOTE_GONE_WAIT):
                    return None
            suspects = self._suspects(generation, fn)  # the first to see this death: every call under way
        if fn not in suspects:  # its worker came from a sandbox that another function's call ended
            return "innocent"
        return "alone" if len(suspects) == 1 else "shared"

    def close(self):
        self.box.close()


class _FunctionRun:
    """One contract function's grading, in two phases on one worker and one set of budgets: its public tests, then,
    once every function's public tests have run, its hidden ones (:func:`_grade`). Nothing a student sees before
    the due date (the public tests' results) is made after a hidden test has started, so no hidden test's inputs
    or outcome can be reported through a public test (the calls a worker received, counted and told in a later
    public test's error, once did)."""

    def __init__(self, ex, fn, grading, ready, limits, seed, budget):
        self.ex, self.fn, self.grading, self.limits, self.seed, self.budget = ex, fn, grading, limits, seed, budget
        self.tests = ex.tests_for(fn)
        self.vis = {t.name: VISIBILITY[t.visibility] for t in self.tests}
        self.out = {}  # test name -> TestResult
        self.state = {}
        self.caller = None
        info = (ready.get("functions") or {}).get(fn) or {}
        unit_files = {u["filename"] for u in grading.box.units}
        module = info.get("module") or ""
        filename = info.get("filename")
        if not info.get("defined"):
            self._zero(self.tests, f"FAILED\n{fn} is not defined in your submission")
        elif not info.get("callable"):
            self._zero(self.tests, f"FAILED\n{fn} is defined but is not a function")
        elif (isinstance(module, str) and module.split(".")[0] in FORBIDDEN) or (
                filename is not None and filename not in unit_files and _in_blocked_tree(filename)):
            self._zero(self.tests,
                       f"FAILED\nNo credit: {fn} is not defined by your code (it comes from {module or filename}).")

    def _zero(self, tests, msg):
        for t in tests:
            self.out[t.name] = TestResult(t.name, self.fn, 0.0, t.weight, msg, self.vis[t.name])

    def run(self, hidden):
        """Run the public tests (``hidden`` False) or the hidden ones, each kind in its declared order."""
        fn = self.fn
        tests = [t for t in self.tests if (t.visibility == "hidden") == hidden and t.name not in self.out]
        if not tests:
            return
        if self.caller is None:
            self.caller = _WorkerCaller(self.grading, fn, self.budget)
        results, blocked = run_tests(self.ex, fn, self.caller, seed=self.seed, limits=self.limits,
                                     budget=self.budget, tests=tests, state=self.state)
        self.out.update((r.name, r) for r in results)
        if blocked:
            what = ", ".join(dict.fromkeys(blocked))
            if any(b.startswith(("import ", "open ")) for b in blocked):
                # during the public tests: the whole function; during the hidden ones: those (the public tests'
                # results, seen before the due date, must not tell what happened in a hidden test)
                self._zero(self.tests if not hidden else tests,
                           f"FAILED\nNo credit: while being graded, {fn} tried to use slamlib or the autograder "
                           f"({what}). Graded functions must be your own code.")
            else:
                for r in results:
                    r.output += (f"\nNote: refused while running {fn}: {what} (no processes, network or ctypes "
                                 "while grading)")

    def close(self):
        if self.caller is not None:
            self.caller.close()
            self.caller = None

    def results(self):
        return [self.out[t.name] for t in self.tests if t.name in self.out]


#: Notes on the submission's cells kept in a result: a notebook of thousands of broken cells would otherwise
#: make results.json (and every test's message) many times larger than the notebook.
MAX_NOTES = 20


def _first(items, n, what):
    """The first `n` of `items`, and one more item that counts the rest."""
    return list(items) if len(items) <= n else list(items[:n]) + [f"... and {len(items) - n} {what}"]


def _in_blocked_tree(filename):
    from .sandbox import BLOCKED_PATHS

    try:
        full = os.path.realpath(filename) if os.path.isabs(filename) else filename
    except (ValueError, OSError):  # the submission's word (a code object's file name): NUL, odd characters
        full = filename
    return any(full.startswith(p) for p in BLOCKED_PATHS)


def grade(path, exercise=None, *, limits=None, workers=None, seed=None, functions=None, secret=None):
    """Grade one submission file.

    Parameters
    ----------
    path : str or Path
        ``.ipynb`` or ``.py``.
    exercise : str, optional
        Exercise name; defaults to the one the notebook names in its metadata.
    limits : Limits, optional
        Sandbox resource limits and time budgets.
    workers : int, optional
        Functions graded in parallel (each in its own worker process); default: CPU count.
    seed : int, optional
        Base seed of the scenarios. By default it is derived from the deployment's
        secret and the submission's content (:func:`autograder.seeds.derive_seed`);
        the seed used is in ``GradeResult.seed``, and passing it back reproduces
        the grade exactly.
    functions : list of str, optional
        Grade only these contract functions (the results then hold only their tests).
    secret : str or Path, optional
        File holding the deployment's secret (default: see :mod:`autograder.seeds`).

    Returns
    -------
    GradeResult

    Raises
    ------
    GraderFault
        When the grader's own machinery failed twice (the first fault is followed
        by a second grading, one function at a time, noted in the result).
    """
    check_integer(seed, "seed", 0)
    check_integer(workers, "workers", 1)
    if limits is not None and not isinstance(limits, Limits):
        raise TypeError(f"limits: expected an autograder.sandbox.Limits, got {type(limits).__name__}")
    t0 = time.perf_counter()
    kw = dict(limits=limits, seed=seed, functions=functions, secret=secret)
    try:
        return _grade(path, exercise, workers=workers, final=False, **kw)
    except GraderFault as exc:
        first = exc
    result = _grade(path, exercise, workers=1, final=True, **kw)
    result.loads += getattr(first, "loads", 0)
    result.notes.append(f"graded a second time, one function at a time, after an internal error of the grader "
                        f"({first}); the first grading was discarded")
    result.execution_time = time.perf_counter() - t0
    return result


def _grade(path, exercise, *, limits, workers, seed, functions, secret, final):
    t0 = time.perf_counter()
    start = time.monotonic()
    limits = limits or Limits()
    name = os.path.basename(str(path))
    result = GradeResult(name, None)
    try:
        sub = load_submission(path, max_code=limits.code)
    except SubmissionError as exc:
        sub = None
        load_error, named = str(exc), exc.exercise  # a notebook refused for its size may still name its exercise
    else:
        load_error, named = None, sub.exercise
    ex_name = exercise or named

    def done():
        result.execution_time = time.perf_counter() - t0
        return result

    if ex_name is None:
        result.error = ((load_error + "\n") if load_error else "") + (
            "Cannot tell which exercise this is: pass --exercise NAME (one of " + ", ".join(EXERCISES) + ")")
        return done()
    try:
        ex = get_exercise(ex_name)
    except KeyError:
        result.error = f"Unknown exercise {ex_name!r}; known: {', '.join(EXERCISES)}"
        return done()
    result.exercise = ex.name
    if functions:
        unknown = [f for f in functions if f not in ex.functions]
        if unknown:
            raise ValueError(f"not functions of {ex.name}: {', '.join(unknown)}")
        functions = [f for f in ex.functions if f in functions]
    else:
        functions = list(ex.functions)
    if load_error:
        result.error = f"The submission could not be read: {load_error}"
        result.tests = _zero_all(ex, f"FAILED\n{load_error}", functions)
        return done()
    result.submission_sha256 = sub.sha256
    if seed is None:
        from .seeds import derive_seed, load_secret

        seed = derive_seed(load_secret(secret), ex.name, sub.sha256)
    result.seed = int(seed)
    result.notes.extend(_first(sub.notes, MAX_NOTES, "more notes on the submission's cells"))
    if sub.exercise and sub.exercise != ex.name:
        msg = (f"This is the notebook of exercise {sub.exercise!r}, but it was submitted for {ex.name!r}: "
               f"submit {ex.notebook}.")
        result.error = msg
        result.tests = _zero_all(ex, "FAILED\n" + msg, functions)
        return done()
    if not any(u["source"].strip() for u in sub.units):
        msg = "The submission contains no code."
        result.error = msg
        result.tests = _zero_all(ex, "FAILED\n" + msg, functions)
        return done()
    forbidden = forbidden_usage(sub.units, list(ex.functions))
    budget_args = (limits.test_budget or ex.test_budget, limits.submission_budget or ex.submission_budget)
    grading = _Grading(sub, list(ex.functions), limits, final=final)
    outs = {}
    try:
        try:
            ready = grading.start()
        except ChildFailed as exc:
            if exc.reason == "eof" and not final:  # its process ended abruptly twice: the machine's doing, perhaps
                raise SandboxLost(f"loading: {exc.outcome.error}") from None
            ready = None
            load_failure = exc.outcome.error
        result.loads = grading.box.loads
        todo = []
        for fn in functions:
            tests = ex.tests_for(fn)
            if fn in forbidden:
                outs[fn] = [TestResult(t.name, fn, 0.0, t.weight,
                                       f"FAILED\nNo credit: {forbidden[fn]}. Graded functions must be your own code "
                                       "(NumPy, SciPy and the standard library are fine; slamlib and the autograder "
                                       "are not).", VISIBILITY[t.visibility]) for t in tests]
            elif ready is None:
                outs[fn] = [TestResult(t.name, fn, 0.0, t.weight, f"FAILED\n{load_failure}", VISIBILITY[t.visibility])
                            for t in tests]
            else:
                todo.append(fn)
        if ready is not None:
            result.isolation = ready.get("isolation") or {}
            for n in _first(ready.get("notes") or [], MAX_NOTES, "more notes from loading the submission"):
                result.notes.append(f"while loading: {n}")
        n_workers = workers or min(len(todo), os.cpu_count() or 2) or 1

        # the functions' budgets run from before the first loading, and what of it was no one's comes back to them
        shared = NoOnesTime(budget_args[1])
        shared.take(grading.box.waited)
        # the grader's pauses between calls are given back only where no process of the sandbox can cause them
        pauses = bool(((ready or {}).get("isolation") or {}).get("seccomp"))
        runs = {fn: _FunctionRun(ex, fn, grading, ready, limits, seed,
                                 Budget(*budget_args, start=start, shared=shared, count_pauses=pauses))
                for fn in todo}

        def each(hidden):
            # every function's public tests first, then every function's hidden tests: what a student sees before
            # the due date is all made before the first hidden test starts
            def one(fn):
                runs[fn].run(hidden)

            if n_workers <= 1:
                for fn in todo:
                    one(fn)
            else:
                with ThreadPoolExecutor(max_workers=n_workers) as pool:
                    list(pool.map(one, todo))

        try:
            if todo:
                each(False)
                each(True)
        finally:
            for run in runs.values():
                run.close()
        for fn, run in runs.items():
            out = run.results()
            if sub.syntax_errors and out and "is not defined in your submission" in out[0].output:
                extra = (" (some cells could not be read: " + "; ".join(_first(
                    [f"{k}: {v}" for k, v in sub.syntax_errors.items()], 3, "more cells that could not be read")) + ")")
                for r in out:
                    r.output = r.output.replace("is not defined in your submission",
                                                "is not defined in your submission" + extra, 1)
            outs[fn] = out
        result.loads = grading.box.loads
    except GraderFault as exc:
        exc.loads = grading.box.loads  # a second grading adds its own loadings to these (grade)
        raise
    finally:
        grading.close()
    for fn in functions:
        result.tests.extend(outs.get(fn, []))
    return done()
