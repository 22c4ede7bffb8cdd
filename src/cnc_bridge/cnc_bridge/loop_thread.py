"""Event loops for the asyncio libraries (OPC UA client, CNC emulator), driven from synchronous code.

The OPC UA client and the CNC emulator are asyncio libraries; the ROS node and the tests
are synchronous. Two ways to drive a loop, with one interface (``run``, ``submit``,
``wait``, ``serve``, ``stop``):

* :class:`LoopThread`: the loop runs forever in its own thread; :meth:`LoopThread.run`
  hands a coroutine over and waits for its result with a deadline. Background tasks
  (reconnection, keep-alive) run whenever they are due. Each call costs two thread wakes
  (the loop's thread, then the caller's) and the two threads contend for the GIL.
* :class:`InlineLoop`: the loop belongs to the calling thread and runs only while that
  thread drives it: :meth:`InlineLoop.run` runs the coroutine to completion there (no
  hop), and :meth:`InlineLoop.serve`, called periodically (the bridge node's timer),
  serves the background tasks in between. Used by the cnc_bridge node, whose OPC UA
  write sits on the temperature-to-offsets latency path (docs/cnc_bridge.md).
"""
from __future__ import annotations

import asyncio
import threading
from typing import Any, Coroutine


class LoopThread:
    def __init__(self, name: str):
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self.loop.run_forever, name=name, daemon=True)
        self._thread.start()

    def submit(self, coro: Coroutine):
        """Schedule ``coro``; returns a concurrent.futures.Future."""
        return asyncio.run_coroutine_threadsafe(coro, self.loop)

    def run(self, coro: Coroutine, timeout_s: float) -> Any:
        """Run ``coro`` on the loop and wait at most ``timeout_s`` for its result."""
        fut = self.submit(coro)
        try:
            return fut.result(timeout_s)
        except TimeoutError:
            fut.cancel()
            raise

    def wait(self, event: threading.Event, timeout_s: float) -> bool:
        """Wait at most ``timeout_s`` for ``event`` (set by a task on the loop)."""
        return event.wait(timeout_s)

    def serve(self, budget_s: float = 0.0) -> None:
        """Nothing to do: the loop's own thread serves its tasks."""

    def stop(self, timeout_s: float = 5.0) -> None:
        """Cancel every pending task, stop the loop and join the thread."""
        if not self._thread.is_alive():
            return

        async def cancel_rest():
            tasks = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
            for t in tasks:
                t.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
        try:
            self.run(cancel_rest(), timeout_s)
        except Exception:
            pass     # a task that refuses to finish must not block shutdown
        self.loop.call_soon_threadsafe(self.loop.stop)
        self._thread.join(timeout_s)
        if not self._thread.is_alive():
            self.loop.close()


class InlineLoop:
    """A loop owned by the thread that drives it (see the module docstring). Not thread-safe:
    every call must come from the same thread, and none from inside the loop itself."""

    def __init__(self, name: str):
        self.name = name
        self.loop = asyncio.new_event_loop()

    def submit(self, coro: Coroutine) -> asyncio.Task:
        """Schedule ``coro`` as a task; it runs whenever the loop is driven (run, wait, serve)."""
        return self.loop.create_task(coro)

    def run(self, coro: Coroutine, timeout_s: float) -> Any:
        """Run ``coro`` to completion in this thread, at most ``timeout_s`` (then it is
        cancelled and TimeoutError raised); background tasks due meanwhile run too."""
        if self.loop.is_running():
            raise RuntimeError(f"{self.name}: run() called from inside its own loop")
        return self.loop.run_until_complete(asyncio.wait_for(coro, timeout_s))

    def wait(self, event: threading.Event, timeout_s: float) -> bool:
        """Drive the loop until ``event`` is set (by one of its tasks) or ``timeout_s`` passed."""
        async def until_set():
            while not event.is_set():
                await asyncio.sleep(0.005)
        try:
            self.run(until_set(), timeout_s)
        except TimeoutError:
            pass
        return event.is_set()

    def serve(self, budget_s: float) -> None:
        """Drive the loop for ``budget_s``: whatever is ready or falls due meanwhile runs
        (received answers, keep-alives, timers, a reconnection's next steps)."""
        if not self.loop.is_closed():
            self.loop.run_until_complete(asyncio.sleep(budget_s))

    def stop(self, timeout_s: float = 5.0) -> None:
        """Cancel every pending task, give them ``timeout_s`` to finish, close the loop."""
        if self.loop.is_closed():
            return
        tasks = asyncio.all_tasks(self.loop)
        for t in tasks:
            t.cancel()
        if tasks:
            self.loop.run_until_complete(asyncio.wait(tasks, timeout=timeout_s))
        self.loop.close()
