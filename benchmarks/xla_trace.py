"""XLA's CPU profile of a call, for the profiling benchmarks (``loss_profile.py``,
``solve_profile.py``): the trace's complete events and each name's self time."""
from __future__ import annotations

import collections
import glob
import gzip
import json
import os
import tempfile


def traced_events(run) -> list:
    """The complete trace events (perfetto JSON) of ``run()`` under
    ``jax.profiler.trace``: XLA's CPU thunks, the Python frames and the runtime's own."""
    import jax

    with tempfile.TemporaryDirectory() as d:
        with jax.profiler.trace(d, create_perfetto_trace=True):
            run()
        path = glob.glob(os.path.join(d, "**", "*.trace.json.gz"), recursive=True)[0]
        with gzip.open(path) as fh:
            events = json.load(fh)
    return events["traceEvents"] if isinstance(events, dict) else events


def self_times(events) -> dict:
    """{name: [self microseconds, count]} of complete events: each event's
    duration less the events nested in it on the thread it ran on."""
    by_thread = collections.defaultdict(list)
    for e in events:
        if e.get("ph") == "X" and "dur" in e:
            by_thread[(e.get("pid"), e.get("tid"))].append(e)
    out = collections.defaultdict(lambda: [0.0, 0])
    for es in by_thread.values():
        es.sort(key=lambda e: (e["ts"], -e["dur"]))
        stack, child = [], collections.Counter()
        for i, e in enumerate(es):
            while stack and es[stack[-1]]["ts"] + es[stack[-1]]["dur"] <= e["ts"]:
                stack.pop()
            if stack:
                child[stack[-1]] += e["dur"]
            stack.append(i)
        for i, e in enumerate(es):
            out[e["name"]][0] += e["dur"] - child[i]
            out[e["name"]][1] += 1
    return out
