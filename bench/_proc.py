"""Resident memory and CPU time of a process tree (a `byc up` graph), read from /proc; shared by
soak.py and bench_idle_cpu.py."""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

PAGE_SIZE = os.sysconf("SC_PAGE_SIZE")
TICKS = os.sysconf("SC_CLK_TCK")
_STARTED = re.compile(r"started (\S+) \(pid (\d+)\)")


@dataclass
class Series:
    times: list[float] = field(default_factory=list)
    rss_mb: list[float] = field(default_factory=list)
    cpu_s: list[float] = field(default_factory=list)

    def cpu_percent(self, since: float = float("-inf")) -> float:
        """Mean CPU (% of one core) over the samples taken at or after `since`."""
        picked = [i for i, at in enumerate(self.times) if at >= since]
        if len(picked) < 2:
            return float("nan")
        first, last = picked[0], picked[-1]
        span = self.times[last] - self.times[first]
        return 100.0 * (self.cpu_s[last] - self.cpu_s[first]) / span if span else float("nan")


def _children(pid: int) -> list[int]:
    found = []
    try:
        for task in os.listdir(f"/proc/{pid}/task"):
            text = Path(f"/proc/{pid}/task/{task}/children").read_text()
            found += [int(child) for child in text.split()]
    except OSError:
        pass
    return found


def sample_tree(root: int, at: float, series: dict[int, Series]) -> None:
    """Append one sample (RSS, user+system CPU seconds) for `root` and every descendant."""
    pending = [root]
    while pending:
        pid = pending.pop()
        pending += _children(pid)
        try:
            rss_pages = int(Path(f"/proc/{pid}/statm").read_text().split()[1])
            stat = Path(f"/proc/{pid}/stat").read_text()
        except (OSError, IndexError, ValueError):
            continue  # ended between the listing and the read
        fields = stat[stat.rindex(")") + 2 :].split()
        entry = series.setdefault(pid, Series())
        entry.times.append(at)
        entry.rss_mb.append(rss_pages * PAGE_SIZE / 2**20)
        entry.cpu_s.append((int(fields[11]) + int(fields[12])) / TICKS)  # utime + stime


def process_names(graph_log: Path) -> dict[int, str]:
    """pid → node or agent name, from byc up's "started NAME (pid N)" lines."""
    found = _STARTED.finditer(graph_log.read_text(errors="replace")) if graph_log.exists() else ()
    return {int(match[2]): match[1] for match in found}
