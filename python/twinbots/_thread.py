"""An env's simulation lives on the thread that created it (a Bevy app is not shared between
threads; the extension's `Arenas` is pinned to its thread). Using it from another thread is a
`RuntimeError` here, before the extension's own check would raise a `PanicException`."""

from __future__ import annotations

import functools
import threading

get_ident = threading.get_ident


def wrong_thread(owner: int) -> RuntimeError:
    return RuntimeError(
        f"this twinbots env was created on thread {owner} and cannot be used on thread {get_ident()}: "
        "create one env per thread (or use gymnasium's AsyncVectorEnv / SB3's SubprocVecEnv for processes)"
    )


def on_owner_thread(method):
    """Runs `method` only on the thread that created the env (`self._owner`), else raises
    `wrong_thread`."""

    @functools.wraps(method)
    def checked(self, *args, **kwargs):
        if get_ident() != self._owner:
            raise wrong_thread(self._owner)
        return method(self, *args, **kwargs)

    return checked
