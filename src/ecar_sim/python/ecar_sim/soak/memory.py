"""Resident memory over time: samples of a process's VmRSS, and the growth of each server life
after its warm-up.

A server life is the time between two kills; its growth compares the median of the samples in
the WINDOW_S after warm-up with the median of its last WINDOW_S (medians: one sample taken while
a bundle adjustment holds a few MB more says nothing about a trend). A life shorter than
warm-up + 2 windows is reported but not judged.

    rss_kib(pid)                        # 123456, or None when the process is gone
    growth(samples, warmup=120.0)       # [Life(index, start, end, base_kib, end_kib, percent)]
"""

import collections
import statistics

WINDOW_S = 30.0

Sample = collections.namedtuple("Sample", "t life server_kib devices_kib")
Life = collections.namedtuple("Life", "index start end base_kib end_kib percent judged")


def rss_kib(pid):
    """The resident set size of process pid in KiB (VmRSS of /proc/<pid>/status), or None."""
    if not pid:
        return None
    try:
        with open("/proc/%d/status" % pid) as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        return None
    return None


def growth(samples, warmup):
    """One Life per server life in samples (a list of Sample in time order): its memory at the
    end of warm-up (base), at its end, and the growth in percent (None when too short)."""
    lives = collections.OrderedDict()
    for s in samples:
        if s.server_kib is not None:
            lives.setdefault(s.life, []).append(s)
    out = []
    for index, life in lives.items():
        start, end = life[0].t, life[-1].t
        base = [s.server_kib for s in life if start + warmup <= s.t < start + warmup + WINDOW_S]
        last = [s.server_kib for s in life if s.t > end - WINDOW_S]
        judged = end - start >= warmup + 2 * WINDOW_S and base and last
        if judged:
            b, e = statistics.median(base), statistics.median(last)
            out.append(Life(index, start, end, b, e, 100.0 * (e - b) / b, True))
        else:
            out.append(Life(index, start, end, None, life[-1].server_kib, None, False))
    return out
