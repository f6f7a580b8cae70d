"""Record what the grader passes to each contract function, and replay it: the seed-independence audit.

:class:`RecordingCaller` runs the grader's tests in-process on ``slamlib`` and keeps,
per test, the key of every call's inputs (a hash of the arrays' bytes, the numbers and
the state of any generator argument) and ``slamlib``'s answer. From two recordings
under different seeds, :func:`audit` lists the tests whose inputs are all the same
(a submission that recorded the answers once would earn them in every grading);
:func:`lookup_submission` writes a submission that computes nothing and returns the
recorded answers (the attack the seeds must defeat).

Run as a script for a report: ``python tests/autograder_fixtures/recording.py``.
"""

from __future__ import annotations

import base64
import hashlib
import io
import json
import sys
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import slamlib  # noqa: E402
from autograder.engine import run_tests  # noqa: E402
from autograder.exercises import EXERCISES, get_exercise  # noqa: E402
from autograder.selfcheck import InProcessCaller  # noqa: E402
from autograder.wire import RngSeed  # noqa: E402

# The key function, as source: the lookup submission defines the same function, so that the keys computed
# while grading (on the arguments the child received) match the keys recorded here.
KEY_SOURCE = '''
def _key(fn, args, kwargs):
    import hashlib, json
    import numpy as np
    h = hashlib.sha256(fn.encode())

    def feed(v):
        if isinstance(v, np.random.Generator):
            h.update(b"G" + json.dumps(v.bit_generator.state, sort_keys=True, default=str).encode())
        elif isinstance(v, np.ndarray):
            a = np.ascontiguousarray(v, dtype=float)
            h.update(b"A" + str(a.shape).encode() + a.tobytes())
        elif isinstance(v, (bool, np.bool_)):
            h.update(b"B" + str(bool(v)).encode())
        elif isinstance(v, (int, np.integer)):
            h.update(b"I" + str(int(v)).encode())
        elif isinstance(v, (float, np.floating)):
            h.update(b"F" + float(v).hex().encode())
        elif v is None:
            h.update(b"N")
        else:
            h.update(b"?" + repr(v).encode())

    for a in args:
        feed(a)
    for k in sorted(kwargs):
        h.update(k.encode())
        feed(kwargs[k])
    return h.hexdigest()
'''
_ns = {}
exec(KEY_SOURCE, _ns)  # noqa: S102 - our own constant source
key = _ns["_key"]


def _live(v):
    return np.random.default_rng(v.seed) if isinstance(v, RngSeed) else v


class RecordingCaller(InProcessCaller):
    """An in-process caller on ``slamlib`` that records (key, answer) per call, grouped by the current test."""

    def __init__(self):
        super().__init__({fn: getattr(slamlib, fn) for fns in _contract().values() for fn in fns})
        self.test = None
        self.calls = {}  # test name -> list of keys
        self.answers = {}  # key -> (fn, answer)
        self.shapes = {}  # key -> shapes of the positional arguments

    def call(self, fn, args, kwargs, *, timeout=None, names=(), global_seed=None):
        k = key(fn, [_live(a) for a in args], {n: _live(v) for n, v in kwargs.items()})
        self.calls.setdefault(self.test, []).append(k)
        self.shapes[k] = [list(np.shape(a)) for a in args]
        if k not in self.answers:
            f = getattr(slamlib, fn)
            try:
                out = f(*[_live(a) for a in args], **{n: _live(v) for n, v in kwargs.items()})
            except Exception:  # noqa: BLE001 - an input slamlib rejects: nothing to record
                out = None
            if out is not None:
                self.answers[k] = (fn, out)
        return super().call(fn, args, kwargs, timeout=timeout, names=names, global_seed=global_seed)


def _contract():
    return {name: list(get_exercise(name).functions) for name in EXERCISES}


class _TestRecorder:
    """An exercise whose ``tests_for`` marks the current test on the caller before it runs."""

    def __init__(self, ex, caller):
        self._ex, self._caller = ex, caller
        self.name = ex.name
        self.seed = ex.seed

    def params(self, fn):
        return self._ex.params(fn)

    def tests_for(self, fn):
        for t in self._ex.tests_for(fn):
            self._caller.test = t.name
            yield t


def record(exercise, seed, functions=None):
    """Run every test (public and hidden) of ``exercise`` on slamlib under ``seed``; return the caller."""
    ex = get_exercise(exercise)
    caller = RecordingCaller()
    for fn in ex.functions:
        if functions and fn not in functions:
            continue
        results, _ = run_tests(_TestRecorder(ex, caller), fn, caller, seed=seed)
        bad = [r.name for r in results if r.score != r.max_score]
        if bad:
            raise AssertionError(f"slamlib fails {bad} under seed {seed}")
    return caller


def audit(exercise, seed_a=1111, seed_b=2222):
    """Tests of ``exercise`` whose every input under ``seed_b`` was already seen under ``seed_a``.

    Returns ``{test name: number of calls}`` for the tests a recorded-answers
    submission could pass (an empty dict: every test has seeded inputs).
    """
    a, b = record(exercise, seed_a), record(exercise, seed_b)
    seen = set(k for ks in a.calls.values() for k in ks)
    return {t: len(ks) for t, ks in b.calls.items() if all(k in seen for k in ks)}


def _enc(v):
    if hasattr(v, "toarray"):  # a scipy.sparse result: its dense form
        v = v.toarray()
    if isinstance(v, tuple):
        return {"tuple": [_enc(x) for x in v]}
    if isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_)):
        return {"int": int(v)}
    if isinstance(v, float):
        return {"float": v.hex()}
    buf = io.BytesIO()
    np.save(buf, np.asarray(v), allow_pickle=False)
    return {"npy": base64.b64encode(buf.getvalue()).decode()}


LOOKUP_TEMPLATE = '''
import base64, io, json, zlib
import numpy as np
{key}
_TABLE = json.loads(zlib.decompress(base64.b64decode({table!r})).decode())


def _dec(v):
    if "tuple" in v:
        return tuple(_dec(x) for x in v["tuple"])
    if "int" in v:
        return v["int"]
    if "float" in v:
        return float.fromhex(v["float"])
    return np.load(io.BytesIO(base64.b64decode(v["npy"])), allow_pickle=False)


def _answer(fn, args, kwargs):
    hit = _TABLE["answers"].get(_key(fn, args, kwargs))
    if hit is not None:
        return _dec(hit)
    # a miss: the recorded answer of a call with the same input shapes (wrong, but of the right form)
    shapes = [list(np.shape(a)) for a in args]
    for cand in _TABLE["by_fn"].get(fn, []):
        if cand["shapes"] == shapes:
            return _dec(_TABLE["answers"][cand["key"]])
    raise RuntimeError("no recorded answer")

{defs}
'''


def lookup_submission(callers, path):
    """Write a ``.py`` submission answering every call recorded by ``callers`` (a lookup table, nothing computed)."""
    answers, by_fn, sigs = {}, {}, {}
    for c in callers:
        for k, (fn, out) in c.answers.items():
            answers[k] = _enc(out)
    for name in EXERCISES:
        ex = get_exercise(name)
        for fn, sig in ex.functions.items():
            sigs[fn] = sig
    # shapes of recorded inputs are not kept per key; store the answers' keys per function, shapes from a replay
    for c in callers:
        for k, (fn, out) in c.answers.items():
            by_fn.setdefault(fn, []).append({"key": k, "shapes": c.shapes.get(k)})
    blob = base64.b64encode(__import__("zlib").compress(json.dumps({"answers": answers, "by_fn": by_fn}).encode(), 6))
    defs = []
    for fn, sig in sigs.items():
        params = sig.strip("()").replace(" ", "")
        names = [p for p in params.split(",") if p and p != "*"]
        star = "*" in params.split(",")
        pos = [p for p in params.split(",")[: params.split(",").index("*")]] if star else names
        kw = [p for p in names if p not in pos]
        call_kw = "{" + ", ".join(f"{p!r}: {p}" for p in kw) + "}"
        defs.append(f"def {fn}{sig}:\n    return _answer({fn!r}, [{', '.join(pos)}], {call_kw})\n")
    Path(path).write_text(LOOKUP_TEMPLATE.format(key=KEY_SOURCE, table=blob.decode(), defs="\n\n".join(defs)))
    return path


def main():
    for name in EXERCISES:
        a, b = record(name, 1111), record(name, 2222)
        seen = set(k for ks in a.calls.values() for k in ks)
        same = {t: ks for t, ks in b.calls.items() if all(k in seen for k in ks)}
        print(f"{name}: {len(same)} test(s) with the same inputs under two seeds")
        for t, ks in b.calls.items():
            shared = sum(k in seen for k in ks)
            if shared:
                print(f"  {'SAME ' if t in same else 'mixed'} {t}: {shared} of {len(ks)} calls shared")


if __name__ == "__main__":
    main()
