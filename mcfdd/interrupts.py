"""Ctrl-C in the ``mcfdd`` command (the edge): honoured in every phase, with status 130 and one line.

Three things stood between an interrupt and a clean exit: Python ignores a ``KeyboardInterrupt``
raised in a garbage-collection callback (JAX registers one), an interrupt inside the import of
jaxlib's native module crashed the process, and the interpreter's shutdown crashed under a
compilation the interrupt had abandoned.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from multiprocessing import util

INTERRUPTED = 130  # exit status after Ctrl-C (SIGINT), as a shell gives it


def stop_now(code: int):
    """End this process at once with status ``code``, its output flushed, without tearing down JAX's runtime.

    An interrupt can leave an XLA compilation running on the runtime's thread pool: JAX compiles
    asynchronously and the interrupt breaks only the wait for it. The interpreter's shutdown then
    destroys the PjRt client under that compilation (its devices before its compile threads),
    and the process died by SIGSEGV after its "interrupted" line. What is worth keeping is on
    disk already (each part is written whole and renamed into place; the kernel releases the
    folder's lock), so the process ends here instead of shutting the runtime down; only
    multiprocessing's exit handler runs first, so the semaphores of a local Dask cluster closed on
    the way are released (else its resource tracker reports them leaked).
    """
    util._exit_function()  # multiprocessing's own exit handler: a closed local cluster's semaphores released
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def redeliver_ignored(unraisable):
    """An interrupt that lands in a garbage-collection callback (JAX registers one; imports collect often) is
    ignored by Python, and the command went on; it is raised again 50 ms later (a SIGALRM), once this hook has
    returned, and again until it lands in the command's own code."""
    if issubclass(unraisable.exc_type, KeyboardInterrupt) and hasattr(signal, "setitimer"):  # not on Windows
        signal.signal(signal.SIGALRM, _interrupt_again)
        signal.setitimer(signal.ITIMER_REAL, 0.05)
    else:
        sys.__unraisablehook__(unraisable)


def _interrupt_again(signum, frame):
    if frame is not None and frame.f_code is redeliver_ignored.__code__:
        signal.setitimer(signal.ITIMER_REAL, 0.05)  # still in the hook, where an exception would be ignored
        return
    raise KeyboardInterrupt


@contextlib.contextmanager
def held():
    """Ctrl-C held while the block runs (in the main thread), then honoured as a ``KeyboardInterrupt``.

    For the few seconds the command imports JAX and starts its devices: an interrupt inside the
    import of jaxlib's native module crashed the process (SIGSEGV in nanobind's teardown of the
    half-made module).
    """
    caught = []
    main_thread = threading.current_thread() is threading.main_thread()  # signal handlers are set there only
    previous = signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum)) if main_thread else None
    try:
        yield
    finally:
        if main_thread:
            signal.signal(signal.SIGINT, previous)
    if caught:
        raise KeyboardInterrupt
