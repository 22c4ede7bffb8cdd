"""An asyncio event loop running in its own thread, driven from synchronous code.

The OPC UA client and the CNC emulator are asyncio libraries; the ROS node and the tests
are synchronous. Each owns one :class:`LoopThread`; :meth:`run` submits a coroutine and
waits for it with a deadline, :meth:`stop` cancels whatever is still pending and joins.
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
