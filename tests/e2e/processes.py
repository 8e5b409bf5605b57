"""Stopping the processes the end-to-end suites start (drives, fw-sim, the
page, a master tool): one way for all of them, so that none is left running
to hold a port or a pty for the next test."""

from __future__ import annotations

import signal
import subprocess
from typing import IO

STOP_TIMEOUT_S = 5.0


def stop_process(proc: subprocess.Popen, *logs: IO, sig: int = signal.SIGTERM,
                 timeout: float = STOP_TIMEOUT_S) -> int | None:
    """Sends `sig` (then SIGKILL after `timeout` s) unless `proc` has ended,
    closes its stdout and the `logs` it wrote to; returns its exit status
    (None if even SIGKILL did not end it within `timeout`)."""
    try:
        if proc.poll() is None:
            proc.send_signal(sig)
            try:
                proc.wait(timeout)
            except subprocess.TimeoutExpired:
                proc.kill()
                try:
                    proc.wait(timeout)
                except subprocess.TimeoutExpired:
                    pass
        return proc.returncode
    finally:
        if proc.stdout:
            proc.stdout.close()
        for f in logs:
            f.close()
