"""Process-wide settings that geofeat changes for the length of a call, and puts back after it.

torch keeps its TF32 switches (the GPU path turns them off: `GeoPatch.describe_tensor`,
`match(..., device="cuda")`) per process, not per thread, and its intra-op thread count
(`GeoPatch(threads=...)` sets it) partly so. Saving the value, setting it and restoring it in each
call is not enough when calls overlap in several threads: a call that starts while another has the
setting changed saves that call's value, and restores it after the other has put the caller's
back, so that the caller's setting stays changed for good. `override` keeps one saved value for
all the calls that overlap, and the last of them to leave restores it; `torch_threads` lets one
call at a time set the thread count.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

_changed = threading.Condition()
#: name -> [the value found before the first overlapping call, the value set, calls inside]
_active: dict[str, list] = {}


@contextmanager
def override(name: str, get: Callable[[], Any], set: Callable[[Any], None], value: Any) -> Iterator[None]:
    """Give the process-wide setting `name` (read by `get()`, written by `set(v)`) the value `value`
    for the body, and put back the value it had before when the last overlapping call leaves.
    Calls in other threads that want the same value run alongside; one that wants another value
    waits until the setting is free (the setting is the process's: two values cannot hold at
    once). Within one thread, nest only calls that want the same value of a setting."""
    with _changed:
        while name in _active and _active[name][1] != value:
            _changed.wait()
        entry = _active.get(name)
        if entry is None:
            entry = _active[name] = [get(), value, 0]
            set(value)
        entry[2] += 1
    try:
        yield
    finally:
        with _changed:
            entry[2] -= 1
            if entry[2] == 0:
                del _active[name]
                set(entry[0])
                _changed.notify_all()


#: Held by the calls that set torch's threads (`torch_threads`), one at a time.
_torch_threads = threading.Lock()


@contextmanager
def torch_threads(threads: int | None) -> Iterator[None]:
    """torch's intra-op threads set to `threads` for the body, then restored; None: left as they
    are, nothing set. torch keeps the count per thread (OpenMP's) and once for the process (the
    count a thread takes when it first runs torch), and sets both: the calls that set it run one
    at a time, so that each restores what it found, not another call's value."""
    if threads is None:
        yield
        return
    import torch

    with _torch_threads:
        before = torch.get_num_threads()
        torch.set_num_threads(int(threads))
        try:
            yield
        finally:
            torch.set_num_threads(before)


@contextmanager
def no_tf32(cudnn: bool = True) -> Iterator[None]:
    """TF32 off for torch's CUDA matrix products (and cuDNN's convolutions, unless `cudnn` is
    False) for the body (`override`): fp32 results that equal the CPU's within 1e-4."""
    import torch

    def setter(module):
        return lambda flag: setattr(module, "allow_tf32", flag)

    matmul = torch.backends.cuda.matmul
    with override("torch.cuda.matmul.allow_tf32", lambda: matmul.allow_tf32, setter(matmul), False):
        if not cudnn:
            yield
            return
        backend = torch.backends.cudnn
        with override("torch.backends.cudnn.allow_tf32", lambda: backend.allow_tf32, setter(backend), False):
            yield
