"""Running work in a pool of spawned worker processes tied to this one's life: each a fresh
interpreter (safe with EGL contexts and torch threads) on one thread, that exits when its parent
dies, even by SIGKILL, so no orphan keeps writing. ``render`` renders the shards with it."""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from typing import TypeVar

_PR_SET_PDEATHSIG = 1  # <linux/prctl.h>

#: What ``run`` hands its function, and what the function gives back.
Argument = TypeVar("Argument")
Result = TypeVar("Result")


def default_workers() -> int:
    """The number of cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def run_in_workers(
    function: Callable[[Argument], Result], arguments: Sequence[Argument], workers: int, died: str
) -> Iterator[Result]:
    """Yield ``function(argument)`` for each of ``arguments`` as each finishes: in this process
    for one worker or one argument, else in a pool of ``workers`` spawned processes. A worker
    that dies raises a RuntimeError saying ``died`` instead of hanging; on any error, arguments
    not started are dropped and running ones finish."""
    if workers == 1 or len(arguments) <= 1:
        yield from (function(argument) for argument in arguments)
        return
    context = multiprocessing.get_context("spawn")
    others = set(multiprocessing.active_children())
    pool = ProcessPoolExecutor(
        min(workers, len(arguments)), context, initializer=_init_worker, initargs=(os.getpid(),)
    )
    with pool:
        with _interrupts_ignored():  # the workers spawned now inherit it: Ctrl-C is ours
            futures = [pool.submit(function, argument) for argument in arguments]
        try:
            for future in as_completed(futures):
                yield future.result()
        except BrokenProcessPool as error:
            raise RuntimeError(died) from error
        except KeyboardInterrupt:
            # Ctrl-C stops the workers too, at once (a shard being written is left out whole:
            # it is written by rename), rather than after the shards they are rendering.
            for child in set(multiprocessing.active_children()) - others:
                child.terminate()
            raise
        finally:
            for future in futures:
                future.cancel()


@contextlib.contextmanager
def _interrupts_ignored() -> Iterator[None]:
    """Ignore SIGINT (Ctrl-C) within, in the main thread: processes spawned within inherit it,
    so the terminal's Ctrl-C, sent to every process of the group, interrupts this process
    alone, which stops them, and no worker prints a KeyboardInterrupt of its own."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _init_worker(parent: int) -> None:
    """Tie the worker's life to its parent's, then use one thread: rendering and physics are
    single-threaded and torch ops are tiny."""
    import torch

    _die_with_parent(parent)
    torch.set_num_threads(1)


def _die_with_parent(parent: int) -> None:
    """Make this process exit when process ``parent`` dies, even by SIGKILL: no orphan keeps
    rendering into the store or holding its EGL context. Linux: the kernel sends SIGKILL
    (prctl PR_SET_PDEATHSIG); elsewhere a daemon thread polls the parent id once a second."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        linked = (
            sys.platform.startswith("linux")
            and libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) == 0
        )
    except (OSError, AttributeError):
        linked = False
    if os.getppid() != parent:  # died before the link was made
        os._exit(1)
    if not linked:

        def watch() -> None:
            while os.getppid() == parent:
                time.sleep(1.0)
            os._exit(1)

        threading.Thread(target=watch, name="die-with-parent", daemon=True).start()
