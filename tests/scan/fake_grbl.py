"""A fake GRBL controller on a pseudo-terminal, for the G-code positioner tests."""

from __future__ import annotations

import os
import pty
import re
import select
import threading
import tty

BANNER = b"\r\nGrbl 1.1h ['$' for help]\r\n[MSG:'$H'|'$X' to unlock]\r\n"


class FakeGrbl:
    """Answers like GRBL 1.1 on the master side of a pty; ``path`` is the port to open.

    Knobs: ``silent_lines`` (ignore that many command lines: a controller that hangs),
    ``deaf`` (ignore even the reset), ``refuse`` (``{line prefix: error code}``), ``run_polls``
    (status reports that say ``Run`` after each move), ``alarm`` (report ``Alarm``).
    """

    def __init__(self, run_polls: int = 2):
        self.master, self._slave = pty.openpty()
        tty.setraw(self._slave)                 # the test keeps a slave fd open: no EIO on the master
        self.path = os.ttyname(self._slave)
        self.lines: list[str] = []
        self.resets = 0
        self.silent_lines, self.deaf, self.alarm = 0, False, False
        self.refuse: dict[str, int] = {}
        self.run_polls, self._running = run_polls, 0
        self.position = (0.0, 0.0)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def close(self):
        self._stop.set()
        self._thread.join()
        os.close(self.master)
        os.close(self._slave)

    def _send(self, text: str | bytes):
        os.write(self.master, text if isinstance(text, bytes) else text.encode() + b"\r\n")

    def _serve(self):
        buffer = b""
        while not self._stop.is_set():
            ready, _, _ = select.select([self.master], [], [], 0.02)
            if not ready:
                continue
            try:
                data = os.read(self.master, 1024)
            except OSError:
                continue
            for byte in data:
                char = bytes([byte])
                if char == b"\x18":
                    if not self.deaf:
                        self.resets += 1
                        buffer = b""
                        self._send(BANNER)
                elif char == b"?":
                    if not self.deaf:
                        self._status()
                elif char == b"\n":
                    self._line(buffer.decode().strip())
                    buffer = b""
                else:
                    buffer += char

    def _status(self):
        state = "Alarm" if self.alarm else ("Run" if self._running else "Idle")
        self._running = max(0, self._running - 1)
        self._send(f"<{state}|MPos:{self.position[0]:.3f},{self.position[1]:.3f},0.000|FS:0,0>")

    def _line(self, line: str):
        self.lines.append(line)
        if self.deaf:
            return
        if self.silent_lines:
            self.silent_lines -= 1
            return
        for prefix, code in self.refuse.items():
            if line.startswith(prefix):
                self._send(f"error:{code}")
                return
        if line.startswith("G0"):
            axes = dict(re.findall(r"([XY])(-?[\d.]+)", line))
            self.position = (float(axes.get("X", self.position[0])), float(axes.get("Y", self.position[1])))
            self._running = self.run_polls
        self._send("ok")
