"""Memory readings from /proc (Linux), shared by the memory budget, tests and benchmarks."""

from __future__ import annotations

import os
import resource


def _kib_field(path: str, key: str) -> int | None:
    """Bytes of a ``key: N kB`` line of a /proc file, or None where it is unavailable."""
    try:
        with open(path) as f:
            for line in f:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def available_memory() -> int:
    """Bytes of RAM available now (Linux MemAvailable; total RAM elsewhere)."""
    v = _kib_field("/proc/meminfo", "MemAvailable")
    return v if v is not None else os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def current_rss() -> int:
    """Resident set of this process now, in bytes (0 where /proc is unavailable)."""
    return _kib_field("/proc/self/status", "VmRSS") or 0


def peak_rss() -> int:
    """Peak resident set of this process in bytes (VmHWM: unlike ru_maxrss it does not
    survive exec, so a child measures only itself)."""
    v = _kib_field("/proc/self/status", "VmHWM")
    return v if v is not None else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # KiB on Linux


def reset_peak_rss() -> int:
    """Reset the peak (VmHWM) to the current RSS where the kernel allows it; returns the
    baseline to subtract from a later :func:`peak_rss`."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        v = _kib_field("/proc/self/status", "VmRSS")
    except OSError:
        v = None
    return v if v is not None else peak_rss()
