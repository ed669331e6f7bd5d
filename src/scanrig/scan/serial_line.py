"""A raw serial line on POSIX (a USB-serial adapter, or a pseudo-terminal in the tests).

pyserial is not a dependency: the few calls a line-based controller needs (open, raw 8N1 at a
baud rate, write, read a line with a time limit) are ``os.open`` + ``termios`` + ``select``.
"""

from __future__ import annotations

import os
import select
import termios
import time
import tty

from scanrig.errors import InputError


class SerialLine:
    """A serial port in raw mode.

    Parameters
    ----------
    path : str
        Device path, e.g. ``/dev/ttyUSB0`` or a pseudo-terminal's slave.
    baud : int
        Line speed; one of the speeds ``termios`` knows (``B115200`` ...).
    """

    def __init__(self, path: str, baud: int = 115200):
        speed = getattr(termios, f"B{baud}", None)
        if speed is None:
            raise InputError(f"baud must be a standard serial speed (e.g. 115200), got {baud!r}")
        self.path = path
        self._fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            tty.setraw(self._fd)
            attrs = termios.tcgetattr(self._fd)
            attrs[4] = attrs[5] = speed
            termios.tcsetattr(self._fd, termios.TCSANOW, attrs)
            termios.tcflush(self._fd, termios.TCIOFLUSH)
        except termios.error:
            os.close(self._fd)
            raise
        self._buffer = b""

    def write(self, data: bytes) -> None:
        """Send bytes (blocks until the kernel took them all)."""
        view = memoryview(data)
        while view:
            _, ready, _ = select.select([], [self._fd], [], 1.0)
            if ready:
                view = view[os.write(self._fd, view):]

    def readline(self, timeout_s: float) -> str | None:
        """Next line without its line ending, or ``None`` if none arrived within ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while b"\n" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            ready, _, _ = select.select([self._fd], [], [], left)
            if ready:
                chunk = os.read(self._fd, 4096)
                if not chunk:
                    raise OSError(f"{self.path}: the line was closed")
                self._buffer += chunk
        line, self._buffer = self._buffer.split(b"\n", 1)
        return line.rstrip(b"\r").decode("ascii", errors="replace")

    def discard_input(self) -> None:
        """Drop anything received but not read."""
        termios.tcflush(self._fd, termios.TCIFLUSH)
        self._buffer = b""

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1
