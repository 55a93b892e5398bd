"""Resident memory over time: samples of a process's VmRSS, and the growth of each server life
after its warm-up.

A server life is the time between two kills; its growth compares the median of the samples in
the WINDOW_S after warm-up with the median of its last WINDOW_S (medians: one sample taken while
a bundle adjustment holds a few MB more says nothing about a trend). A life shorter than
warm-up + 2 windows is reported but not judged.

    rss_kib(pid)                        # 123456, or None when the process is gone
    rss_parts_kib(pid)                  # (anonymous, file-backed) KiB, or (None, None)
    growth(samples, warmup=120.0)       # [Life(index, start, end, base_kib, end_kib, percent)]
    growth(samples, 120.0, "server_anon_kib")   # the same for one part of the memory
"""

import collections
import statistics

WINDOW_S = 30.0

# server_anon_kib: the server's anonymous pages (heap, stacks); server_file_kib: its pages of
# mapped files (the code of its libraries, faulted in as code paths first run).
Sample = collections.namedtuple(
    "Sample", "t life server_kib devices_kib server_anon_kib server_file_kib")
Life = collections.namedtuple("Life", "index start end base_kib end_kib percent judged")


def _status_kib(pid, keys):
    """The values of keys (e.g. "VmRSS") in /proc/<pid>/status, KiB; None for each one missing."""
    found = dict.fromkeys(keys)
    if not pid:
        return [None] * len(keys)
    try:
        with open("/proc/%d/status" % pid) as f:
            for line in f:
                key, _, value = line.partition(":")
                if key in found:
                    found[key] = int(value.split()[0])
    except (OSError, ValueError, IndexError):
        return [None] * len(keys)
    return [found[k] for k in keys]


def rss_kib(pid):
    """The resident set size of process pid in KiB (VmRSS of /proc/<pid>/status), or None."""
    return _status_kib(pid, ("VmRSS",))[0]


def rss_parts_kib(pid):
    """(RssAnon, RssFile) of process pid in KiB: what it allocated, and the pages of files it
    maps (its libraries' code and data) that are resident; (None, None) when it is gone."""
    return tuple(_status_kib(pid, ("RssAnon", "RssFile")))


def growth(samples, warmup, field="server_kib"):
    """One Life per server life in samples (a list of Sample in time order): its memory (field
    of the samples) at the end of warm-up (base), at its end, and the growth in percent (None
    when too short)."""
    lives = collections.OrderedDict()
    for s in samples:
        if getattr(s, field) is not None:
            lives.setdefault(s.life, []).append(s)
    out = []
    for index, life in lives.items():
        start, end = life[0].t, life[-1].t
        base = [getattr(s, field) for s in life
                if start + warmup <= s.t < start + warmup + WINDOW_S]
        last = [getattr(s, field) for s in life if s.t > end - WINDOW_S]
        judged = end - start >= warmup + 2 * WINDOW_S and base and last
        if judged:
            b, e = statistics.median(base), statistics.median(last)
            out.append(Life(index, start, end, b, e, 100.0 * (e - b) / b, True))
        else:
            out.append(Life(index, start, end, None, getattr(life[-1], field), None, False))
    return out
