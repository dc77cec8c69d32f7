"""A bag decoded beside the work on it: a producer (a generator) run in a forked process,
its items handed back in pickled batches, in order.

Decoding a bag (rosbags' reader and CDR deserialisation, the samples' checks) costs about
as much CPU as the estimator's stream work on the samples; on a second core the two
overlap. The items arrive as the same objects to the bit (pickle), in the same order, then
the producer's error: what the consumer computes does not depend on where they were
decoded.
"""

from __future__ import annotations

import multiprocessing
import pickle
import traceback
from collections.abc import Callable, Iterator
from typing import Any, Generic, TypeVar

from rheo_ros.io.errors import BagError

T = TypeVar("T")

BATCH = 1024   # items a message: pickling costs ~1 us an item and ~50 us a message

_MORE, _DONE, _FAILED = 0, 1, 2


class Prefetched(Generic[T]):
    """Iterate ``produce()``'s items, decoded in a forked process (``process``) or here.

    An exception the producer raised is raised here after the items it yielded before it
    (a bug's traceback in the child attached as a note). Used as a context manager, or
    closed: a consumer that stops early ends the child.
    """

    def __init__(self, produce: Callable[[], Iterator[T]], process: bool = True, batch: int = BATCH) -> None:
        self._produce, self._process, self._batch = produce, process, batch
        self._child: Any = None

    def __iter__(self) -> Iterator[T]:
        if not self._process:
            yield from self._produce()
            return
        context = multiprocessing.get_context("fork")   # the child inherits what the parent loaded
        receive, send = context.Pipe(duplex=False)
        self._child = context.Process(target=_run, args=(self._produce, send, self._batch), daemon=True,
                                      name="rheo-bag-reader")
        self._child.start()
        send.close()
        try:
            while True:
                try:
                    items, state, error = pickle.loads(receive.recv_bytes())
                except EOFError:   # the child died without a word (killed)
                    raise RuntimeError(f"the bag's reader process ended (exit code {self._child.exitcode}) "
                                       "before its last sample") from None
                yield from items
                if state == _FAILED:
                    raise error
                if state == _DONE:
                    return
        finally:
            receive.close()
            self.close()

    def close(self) -> None:
        """End the child (a consumer that stopped early leaves it blocked on a full pipe)."""
        if self._child is not None:
            if self._child.is_alive():
                self._child.terminate()
            self._child.join()
            self._child = None

    def __enter__(self) -> Prefetched[T]:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _run(produce: Callable[[], Iterator[Any]], send: Any, batch: int) -> None:
    items: list[Any] = []
    try:
        for item in produce():
            items.append(item)
            if len(items) >= batch:
                send.send_bytes(pickle.dumps((items, _MORE, None), protocol=pickle.HIGHEST_PROTOCOL))
                items = []
        send.send_bytes(pickle.dumps((items, _DONE, None), protocol=pickle.HIGHEST_PROTOCOL))
    except Exception as exc:   # raised in the consumer, after the items before it
        if not isinstance(exc, BagError):   # a bag's fault is its one line; a bug keeps where it was
            exc.add_note("in the bag's reader process:\n" + "".join(traceback.format_exc()))
        try:
            payload = pickle.dumps((items, _FAILED, exc), protocol=pickle.HIGHEST_PROTOCOL)
            pickle.loads(payload)   # an exception class whose arguments do not come back
        except Exception:   # an exception that does not pickle: its type and words
            payload = pickle.dumps((items, _FAILED, RuntimeError(f"{type(exc).__name__}: {exc}")),
                                   protocol=pickle.HIGHEST_PROTOCOL)
        send.send_bytes(payload)
    finally:
        send.close()
