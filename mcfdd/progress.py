"""Progress of long commands (the edge): a tqdm bar on a terminal, plain lines in a log file."""

from __future__ import annotations

import sys

from tqdm import tqdm


class _Lines:
    """A file wrapper turning tqdm's carriage-return redraws into one line each."""

    def __init__(self, stream):
        self.stream, self.last = stream, None

    def write(self, text: str):
        text = text.replace("\r", "").strip()
        if text and text != self.last:
            self.stream.write(text + "\n")
            self.last = text

    def flush(self):
        self.stream.flush()


def bar(total: int, desc: str, enabled: bool, unit: str = "it") -> tqdm:
    """A progress bar over ``total`` units: rate and time left; off when ``enabled`` is False.

    On a terminal the bar redraws in place; when stderr is a file (a batch job's log) it writes a
    plain line at most every 30 s and when done.
    """
    stream = sys.stderr
    if stream.isatty():
        return tqdm(total=total, desc=desc, unit=unit, disable=not enabled, file=stream, dynamic_ncols=True)
    return tqdm(total=total, desc=desc, unit=unit, disable=not enabled, file=_Lines(stream), mininterval=30.0,
                ascii=True, ncols=100)


def note(message: str, enabled: bool):
    """A status line on stderr (above any bar), unless ``enabled`` is False."""
    if enabled:
        tqdm.write(message, file=sys.stderr)
